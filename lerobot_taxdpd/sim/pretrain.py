"""One command from nothing to a shipped goal predictor: demos, `lerobot-train`, held-out evaluation, package.

    python -m lerobot_taxdpd.sim pretrain --task insert_waterproof                 # results/pretrain/<task>
    python -m lerobot_taxdpd.sim pretrain --task mug_easyrack --ship lerobot_taxdpd/pretrained

Steps: scripted demonstrations of the training geometry (`generate`), `lerobot-train` with the shipped CPU
recipe `taxdpd_cpu` (or any recipe name or config file given), the evaluation harness on held-out geometry,
then the checkpoint with its measured metrics (task, training command and budget, held-out success and
errors) saved as a shipped predictor when `--ship` names a folder. Each step that already finished is
reused on a rerun; a checkpoint is reused only by the training command that made it.
"""

from __future__ import annotations

import json
import shlex
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from safetensors.torch import load_file, save_file

from lerobot_taxdpd.recipes import recipe_path, run, train_command
from lerobot_taxdpd.reports.benchmarking import write_json
from lerobot_taxdpd.sim.generate import generate_dataset
from lerobot_taxdpd.sim.harness import evaluate
from lerobot_taxdpd.sim.tasks import get_task
from lerobot_taxdpd.sim.trials import make_trial

#: The recipe of the shipped goal predictors and of `taxdpd-demo --from-scratch`.
CPU_RECIPE = "taxdpd_cpu"
TRAIN_COMMAND_FILE = "train_command.txt"
TRAIN_SECONDS_FILE = "train_seconds.txt"  # kept beside it, so a rerun that ships the same checkpoint reports it


def _relative(path: Path) -> Path:
    """`path` relative to the working directory where it lies below it (commands read better that way)."""
    try:
        return path.resolve().relative_to(Path.cwd())
    except ValueError:
        return path


def save_shipped(policy, checkpoint: Path, destination: Path) -> None:
    """Save a checkpoint the way the package ships it: half-precision weights (half the size; fp16 keeps
    11 mantissa bits, far below the placement errors), config, card, metrics and the saved processors.
    The config forgets the checkpoint it was loaded from (a path on the training machine); a policy that
    keeps an average of its weights ships the average alone, as the weights it samples from."""
    policy = policy.without_ema()
    policy.config.pretrained_path = None
    policy.save_pretrained(destination)
    weights = destination / "model.safetensors"
    save_file({name: tensor.half() for name, tensor in load_file(weights).items()}, weights, metadata={"format": "pt"})
    for processor_file in checkpoint.glob("policy_*processor*"):  # pipelines and their state files
        (destination / processor_file.name).write_bytes(processor_file.read_bytes())


def training_flags(task, steps: int | None, overrides: Sequence[str]) -> list[str]:
    """lerobot-train flags on top of the recipe: the step count, the task's own flags, then the user's (last wins)."""
    return [*([f"--steps={steps}"] if steps else []), *task.training_flags, *overrides]


def pretrain(
    task_name: str,
    output: Path,
    *,
    episodes: int,
    steps: int | None,
    recipe: str | Path,
    trials: int,
    num_samples: int,
    ship: Path | None,
    dataset: Path | None = None,
    overrides: Sequence[str] = (),
) -> dict:
    """Generate, train, evaluate and (optionally) ship one goal predictor; returns its metrics.

    `recipe` is a shipped recipe name or a config file; the task's own `training_flags` follow it, then
    `overrides`, extra lerobot-train flags (`--policy.<field>=<value>`, `--seed=<n>`) that win over both.
    `dataset` (default `<output>/data`) lets several runs, e.g. the ablations of one task, share one set of
    demonstrations; it is generated only if it does not exist yet.
    """
    from lerobot_taxdpd.goal_predictors import load_goal_predictor

    task = get_task(task_name)
    config_path = recipe_path(recipe)
    output = Path(output)
    dataset, run_dir = Path(dataset) if dataset is not None else output / "data", output / "train"
    repo_id = f"local/{task.name}"
    info = dataset / "meta" / "info.json"
    if info.is_file():  # an existing dataset: report what it holds, not what a new one would
        episodes = json.loads(info.read_text())["total_episodes"]
    generate_command = f"python -m lerobot_taxdpd.sim generate --task {task.name} --episodes {episodes} --split train"
    if not info.is_file():
        print(f"[1/4] {episodes} scripted {task.name} demonstrations (training geometry)", flush=True)
        generate_dataset(
            task, episodes=episodes, split="train", repo_id=repo_id, root=dataset, command=generate_command
        )
    flags = training_flags(task, steps, overrides)
    command = train_command(_relative(dataset), repo_id, _relative(run_dir), recipe=_relative(config_path), flags=flags)
    checkpoint = run_dir / "checkpoints" / "last" / "pretrained_model"
    recorded = output / TRAIN_COMMAND_FILE  # what the checkpoint there was trained with
    timing = output / TRAIN_SECONDS_FILE
    if (checkpoint / "model.safetensors").is_file():
        if recorded.is_file() and recorded.read_text() != shlex.join(command):
            raise ValueError(
                f"--output {output}: holds a checkpoint trained by another command ({recorded.read_text()}); "
                "choose another --output or delete that folder"
            )
        train_seconds = float(timing.read_text()) if timing.is_file() else None
    else:
        print(f"[2/4] {shlex.join(command)}", flush=True)
        output.mkdir(parents=True, exist_ok=True)
        recorded.write_text(shlex.join(command))
        train_seconds = run(command)
        timing.write_text(f"{train_seconds}\n")
    policy = load_goal_predictor(checkpoint)
    destination = Path(ship) / task.name if ship is not None else None
    if destination is not None:  # evaluate exactly what ships (half-precision weights)
        save_shipped(policy, checkpoint, destination)
        policy = load_goal_predictor(destination)
    print(f"[3/4] evaluating on {trials} held-out {task.name} trials, K = {num_samples}", flush=True)
    held_out = [make_trial(task, seed, "test") for seed in range(trials)]
    report = evaluate(policy, held_out, num_samples, figures_dir=output / "figures", total=trials)
    orientation = orientation_checks(policy, task, held_out)
    report["predictor"] = str(destination or checkpoint)
    write_json(output / f"{task.name}_eval.json", report)
    train_config = json.loads((checkpoint / "train_config.json").read_text())
    metrics = {
        "task": task.name,
        "description": task.description,
        "data": f"{episodes} scripted demonstrations of the training geometry ({generate_command})",
        "training_command": shlex.join(command),
        "training_steps": train_config["steps"],
        "batch_size": train_config["batch_size"],
        "train_seconds": train_seconds,
        "evaluation": f"{trials} held-out trials (test geometry, seeds 0..{trials - 1}), K = {num_samples}",
        "license": "apache-2.0",
        **{
            key: value
            for key, value in report.items()
            if key in _REPORTED or key.startswith(("coverage@", "precision@"))
        },
        **orientation,
    }
    policy.metrics = metrics
    print(f"[4/4] {task.name}: success {report['success']['success_rate']:.1%} on held-out geometry", flush=True)
    if destination is not None:
        save_shipped(policy, checkpoint, destination)  # same weights, now with the metrics and their card
        print(f"shipped as {destination}")
    (output / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return metrics


def orientation_checks(policy, task, trials: list) -> dict:
    """Does the predictor read orientation off the scene? The equivariance probe on the first held-out trials,
    and the trivial baselines (true position; start or mean goal orientation) on all of them."""
    from lerobot_taxdpd.maths.equivariance import PROBE_SCENES, equivariance_report
    from lerobot_taxdpd.sim.predictors import OraclePredictor

    probe = trials[:PROBE_SCENES]
    equivariance = equivariance_report(
        policy,
        np.stack([t.object_points for t in probe]),
        np.stack([t.scene_points for t in probe]),
        symmetry_period_deg=task.symmetry_period_deg,
    )
    baselines = {}
    for name, orientation in (("copy_start_orientation", "start"), ("mean_goal_orientation", "mean")):
        report = evaluate(OraclePredictor(trials, orientation=orientation), trials, 1, progress=False)
        baselines[name] = {
            "success_rate": report["success"]["success_rate"],
            "rotation_error_deg_median": report["rotation_error_deg"]["median"],
        }
    return {
        "equivariance_deg": equivariance,
        "baselines_true_position": baselines,
    }


_REPORTED = (
    "success",
    "translation_error_mm",
    "rotation_error_deg",
    "rmse_mm",
    "winner_take_all_rmse_mm",
    "gripper_translation_error_mm",
    "gripper_rotation_error_deg",
    "coverage_threshold_mm",
    "seconds_per_trial",
)
