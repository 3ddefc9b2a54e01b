"""One command from nothing to a shipped goal predictor: demos, `lerobot-train`, held-out evaluation, package.

    python -m lerobot_taxdpd.sim pretrain --task insert_waterproof                 # results/pretrain/<task>
    python -m lerobot_taxdpd.sim pretrain --task mug_easyrack --ship lerobot_taxdpd/pretrained

Steps: scripted demonstrations of the training geometry (`generate`), `lerobot-train` with the shipped CPU
recipe `taxdpd_cpu` (or any recipe name or config file given), the evaluation harness on held-out geometry,
then the checkpoint with its measured metrics (task, training command and budget, held-out success and
errors) saved as a shipped predictor when `--ship` names a folder. A rerun reuses the demonstrations and
the checkpoint in place, and says so, only when they were made with the same options and training command;
otherwise it refuses, and `--overwrite` makes them afresh. `--resume-steps N` trains the finished run on to N
steps in a second leg (`lerobot-train --resume=true`), so a long recipe runs in legs that each fit a session.
"""

from __future__ import annotations

import json
import shlex
import shutil
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from safetensors.torch import load_file, save_file

from lerobot_taxdpd.data.dataset_writer import read_card_info
from lerobot_taxdpd.data.schema import METRICS_FILE
from lerobot_taxdpd.recipes import RECIPE_DIR, portable_train_command, recipe_path, run, train_command
from lerobot_taxdpd.reports.benchmarking import write_json
from lerobot_taxdpd.sim.generate import demonstration_details, generate_dataset
from lerobot_taxdpd.sim.harness import evaluate
from lerobot_taxdpd.sim.tasks import get_task
from lerobot_taxdpd.sim.trials import make_trial

#: The recipe of the shipped goal predictors and of `taxdpd-demo --from-scratch`.
CPU_RECIPE = "taxdpd_cpu"
TRAIN_COMMAND_FILE = "train_command.txt"
TRAIN_SECONDS_FILE = "train_seconds.txt"  # kept beside it, so a rerun that ships the same checkpoint reports it
RESUME_COMMAND_FILE = "resume_command.txt"  # the second leg's command and seconds, when the run went on
RESUME_SECONDS_FILE = "resume_seconds.txt"


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


def training_flags(task, steps: int | None, overrides: Sequence[str], init: Sequence[str] = ()) -> list[str]:
    """lerobot-train flags on top of the recipe: the step count, the starting weights' (`init_flags`), the
    task's own flags, then the user's (last wins)."""
    return [*([f"--steps={steps}"] if steps else []), *init, *task.training_flags, *overrides]


#: What a fine-tuned predictor's metrics keep of the one it started from (its own origin too: a chain of legs).
_ORIGIN_KEYS = ("data", "training_command", "training_steps", "initialised_from")


def init_flags(init_from: str, config_path: Path) -> tuple[list[str], list[str], dict]:
    """A run that starts from a goal predictor's weights (fine-tuning): its lerobot-train flags as run here and
    as recorded (a shipped name found on any install), and what the metrics keep of the predictor it started
    from. LeRobot then takes that predictor's own policy config, its architecture, in place of the recipe's;
    the recipe's weight average is put back on top, since a shipped config says use_ema=false (it ships the
    average as its weights). A name that is shipped now may name other weights later, so the metrics keep
    the starting weights' digest and the command that trained them."""
    from lerobot_taxdpd.goal_predictors import list_goal_predictors, resolve_goal_predictor, weights_digest

    folder = resolve_goal_predictor(init_from)
    shipped = list_goal_predictors()
    recorded = f"$(python -m lerobot_taxdpd.goal_predictors path {init_from})" if init_from in shipped else folder
    use_ema = json.loads(config_path.read_text()).get("policy", {}).get("use_ema", False)
    ema = f"--policy.use_ema={str(use_ema).lower()}"
    metrics_file, train_config = Path(folder) / METRICS_FILE, Path(folder) / "train_config.json"
    metrics = json.loads(metrics_file.read_text()) if metrics_file.is_file() else {}
    if "training_command" not in metrics and train_config.is_file():  # a checkpoint of a run, not yet shipped
        metrics["training_command"] = portable_train_command(json.loads(train_config.read_text()))
    origin = {
        "name": init_from,
        "weights": weights_digest(folder),
        **{key: metrics[key] for key in _ORIGIN_KEYS if key in metrics},
    }
    return [f"--policy.path={folder}", ema], [f"--policy.path={recorded}", ema], origin


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
    overwrite: bool = False,
    resume_steps: int | None = None,
    scene_cloud_size: int | None = None,
    init_from: str | None = None,
) -> dict:
    """Generate, train, evaluate and (optionally) ship one goal predictor; returns its metrics.

    `recipe` is a shipped recipe name or a config file; the task's own `training_flags` follow it, then
    `overrides`, extra lerobot-train flags (`--policy.<field>=<value>`, `--seed=<n>`) that win over both.
    `dataset` (default `<output>/data`) lets several runs, e.g. the ablations of one task, share one set of
    demonstrations; it is generated only if it does not exist yet. What a rerun finds in place is reused
    only when made with the same options, and refused otherwise; `overwrite` makes both afresh. `resume_steps`
    trains the finished run on to that many steps in a second leg (see `resume_once`). `scene_cloud_size`
    records and evaluates denser scenes than the task's default (for `--policy.local_scene_points`).
    `init_from` (a shipped name, a checkpoint folder or a Hub id) starts from that predictor's weights and
    architecture instead of random ones (see `init_flags`).
    """
    from lerobot_taxdpd.goal_predictors import load_goal_predictor

    task = get_task(task_name).with_scene_cloud_size(scene_cloud_size)
    config_path = recipe_path(recipe)
    output = Path(output)
    dataset, run_dir = Path(dataset) if dataset is not None else output / "data", output / "train"
    repo_id = f"local/{task.name}"
    init, recorded_init, origin = init_flags(init_from, config_path) if init_from is not None else ([], [], None)
    flags = training_flags(task, steps, overrides, init)
    first_leg = steps or json.loads(config_path.read_text())["steps"]
    if resume_steps is not None and resume_steps <= first_leg:
        raise ValueError(f"--resume-steps {resume_steps}: must be more than the first leg's {first_leg} steps")
    portable_generate, portable_train = portable_commands(
        task, episodes, config_path, training_flags(task, steps, overrides, recorded_init), resume_steps
    )
    for flag in recorded_init:  # a `$(...)` that finds a shipped predictor must run, not be quoted
        portable_train = portable_train.replace(shlex.quote(flag), flag)
    prepare_demonstrations(task, dataset, repo_id, episodes, portable_generate, overwrite=overwrite)
    command = train_command(_relative(dataset), repo_id, _relative(run_dir), recipe=_relative(config_path), flags=flags)
    checkpoint = run_dir / "checkpoints" / "last" / "pretrained_model"
    if overwrite:  # a second leg belongs to the run that is replaced
        for name in (RESUME_COMMAND_FILE, RESUME_SECONDS_FILE):
            (output / name).unlink(missing_ok=True)
    train_seconds = train_once(command, output, run_dir, overwrite=overwrite)
    leg_seconds = resume_once(checkpoint, output, resume_steps)
    if leg_seconds is not None and train_seconds is not None:
        train_seconds += leg_seconds
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
        "data": f"{episodes} scripted demonstrations of the training geometry ({portable_generate})",
        "training_command": portable_train,
        "training_steps": train_config["steps"],
        "batch_size": train_config["batch_size"],
        "train_seconds": train_seconds,
        **({"initialised_from": origin} if origin is not None else {}),
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


def portable_commands(
    task, episodes: int, config_path: Path, flags: Sequence[str], resume_steps: int | None = None
) -> tuple[str, str]:
    """The generate and train commands as metrics and cards record them: runnable on any machine, one after
    the other (folders under the working directory, a shipped recipe by name), not the folders of the
    machine that trained; with `resume_steps`, the train command's second leg after `&&`."""
    data, repo_id, run_dir = f"data/{task.name}", f"local/{task.name}", Path("outputs/train") / task.name
    generate = shlex.join(
        ["python", "-m", "lerobot_taxdpd.sim", "generate", "--task", task.name, "--episodes", str(episodes),
         "--split", "train", "--repo-id", repo_id, "--root", data,
         *(["--scene-cloud-size", str(task.scene_cloud_size)] if task.scene_cloud_size else [])]
    )  # fmt: skip
    train = shlex.join(train_command(Path(data), repo_id, run_dir, flags=flags))
    recipe = shlex.quote(str(_relative(config_path)))
    if config_path.resolve().parent == RECIPE_DIR.resolve():  # found on any install by its name
        recipe = f"$(python -m lerobot_taxdpd.recipes path {config_path.stem})"
    train = train.replace("lerobot-train ", f"lerobot-train --config_path={recipe} ", 1)
    if resume_steps is not None:
        train += f" && {shlex.join(resume_command(run_dir, resume_steps))}"
    return generate, train


def prepare_demonstrations(task, dataset: Path, repo_id: str, episodes: int, command: str, *, overwrite: bool) -> None:
    """Generate the training demonstrations, or reuse those in place when made with the same options: a
    rerun with another `--episodes` must not train on the old ones without a word."""
    if (dataset / "meta" / "info.json").is_file() and not overwrite:
        expected = demonstration_details(task.name, "train", 0, episodes, 2, task.scene_cloud_size)
        differences = _differences(dataset, expected)
        if differences:
            raise ValueError(
                f"{dataset}: holds demonstrations made with other options ({differences}); rerun with the "
                "options they were made with to reuse them, or add --overwrite to make new ones and retrain"
            )
        print(f"[1/4] reusing the {episodes} {task.name} demonstrations in {dataset} (same options)", flush=True)
        return
    print(f"[1/4] {episodes} scripted {task.name} demonstrations (training geometry)", flush=True)
    generate_dataset(
        task, episodes=episodes, split="train", repo_id=repo_id, root=dataset, command=command, overwrite=overwrite
    )


def _differences(dataset: Path, expected: dict) -> str:
    """How the demonstrations in `dataset` differ from `expected` (empty: they match). A dataset written
    elsewhere, without this package's card, is compared by its episode count alone."""
    try:
        held = read_card_info(dataset)[0].details
    except FileNotFoundError:
        total = json.loads((dataset / "meta" / "info.json").read_text())["total_episodes"]
        held = {**expected, "scene seeds": f"0..{total - 1}"}
    keys = [*expected, *(key for key in held if key not in expected)]  # a key absent on one side: its default
    return ", ".join(
        f"{key} {held.get(key, 'default')}, not {expected.get(key, 'default')}"
        for key in keys
        if held.get(key) != expected.get(key)
    )


def train_once(command: list[str], output: Path, run_dir: Path, *, overwrite: bool) -> float | None:
    """Run `lerobot-train` unless `run_dir` holds a checkpoint made by this very command; returns the
    training time (None when an old checkpoint without its time is reused)."""
    recorded = output / TRAIN_COMMAND_FILE  # what the checkpoint there was trained with
    timing = output / TRAIN_SECONDS_FILE
    if (run_dir / "checkpoints" / "last" / "pretrained_model" / "model.safetensors").is_file() and not overwrite:
        if recorded.is_file() and recorded.read_text() != shlex.join(command):
            raise ValueError(
                f"--output {output}: holds a checkpoint trained by another command ({recorded.read_text()}); "
                "choose another --output, or add --overwrite to retrain there"
            )
        print(f"[2/4] reusing the checkpoint in {run_dir} (trained by the same command)", flush=True)
        return float(timing.read_text()) if timing.is_file() else None
    if overwrite and run_dir.exists():
        shutil.rmtree(run_dir)  # lerobot-train refuses an existing output_dir
    print(f"[2/4] {shlex.join(command)}", flush=True)
    output.mkdir(parents=True, exist_ok=True)
    recorded.write_text(shlex.join(command))
    train_seconds = run(command)
    timing.write_text(f"{train_seconds}\n")
    return train_seconds


def resume_command(run_dir: Path, steps: int) -> list[str]:
    """The `lerobot-train` command that trains the run in `run_dir` on to `steps` steps from its last checkpoint
    (its optimizer, scheduler and data order restored; the recipe's cosine then spans the longer run)."""
    config = run_dir / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    return ["lerobot-train", "--resume=true", f"--steps={steps}", f"--config_path={config}"]


def trained_steps(checkpoint: Path) -> int:
    """The steps the run had trained when it saved `checkpoint` (a `pretrained_model` folder)."""
    return int(json.loads((checkpoint.parent / "training_state" / "training_step.json").read_text())["step"])


def resume_once(checkpoint: Path, output: Path, steps: int | None) -> float | None:
    """Train the run whose last checkpoint is `checkpoint` on to `steps` steps, unless it has them already; the
    leg's seconds (None when nothing ran and none were recorded). A leg cut short goes on from its last
    checkpoint when rerun. A resumed run is not evaluated as if it had one leg: without the `steps` it was
    resumed to, it is refused.
    """
    recorded, timing = output / RESUME_COMMAND_FILE, output / RESUME_SECONDS_FILE
    if recorded.is_file():
        trained = trained_steps(checkpoint)
        if steps != trained:
            raise ValueError(
                f"--output {output}: holds a run resumed to {trained} steps ({recorded.read_text()}); rerun with "
                f"--resume-steps {trained} to reuse it, or add --overwrite to retrain there"
            )
        print(f"[2/4] reusing the run resumed to {steps} steps", flush=True)
        return float(timing.read_text()) if timing.is_file() else None
    if steps is None:
        return None
    command = resume_command(_relative(checkpoint.parents[2]), steps)
    print(f"[2/4] {shlex.join(command)}", flush=True)
    seconds = run(command)
    recorded.write_text(shlex.join(command))
    timing.write_text(f"{seconds}\n")
    return seconds


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
