"""Learning curves through `lerobot-train`: held-out quality of every saved checkpoint against training CPU time.

Trains a recipe (default: the shipped CPU recipe, `--set` overrides any policy field) on a task's demos,
keeping a checkpoint every `--save-every` steps, then scores each one on held-out scenes:
- `--task slots`: the synthetic two-slot task at full yaw (rotation, translation, coverage, GMM mass);
- a procedural task (`mug_easyrack`, `insert_waterproof`, ...): the pybullet harness on held-out geometry
  (success with its interval, translation and rotation errors).
Beside every row: the equivariance probe (goal turn when the scene alone, the object alone, or a tilt of the
object alone, is applied; ideal +20, 0, 0 deg) and, once, the trivial baselines (copy the start orientation,
the mean goal orientation; both at the true position). CPU time is the training process's own (user + sys).
`--run-dir` scores the checkpoints of a run that has already finished instead (e.g. one of `sim pretrain`'s,
`<output>/train`), with the wall time that run recorded in place of CPU time.

    python benchmarks/learning_curve.py --task slots --steps 3000 --save-every 500
    python benchmarks/learning_curve.py --task insert_waterproof --dataset data/iw --steps 8000 --save-every 2000 \\
        --set start_tilt_range=15 --output results/curve_iw.json
    python benchmarks/learning_curve.py --task book_shelf --run-dir outputs/book/train --trials 100
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import shutil
from pathlib import Path

import numpy as np
import torch

from lerobot_taxdpd.apps.synthetic import (
    copy_start_rotation_deg,
    evaluate_slot_predictor,
    make_slot_scene,
    write_slot_dataset,
)
from lerobot_taxdpd.goal_predictors import load_goal_predictor
from lerobot_taxdpd.maths.equivariance import goal_turn_response
from lerobot_taxdpd.recipes import (
    add_policy_overrides_argument,
    policy_flags,
    portable_train_command,
    recipe_path,
    run,
    train_command,
)
from lerobot_taxdpd.reports.benchmarking import machine_info, write_json
from lerobot_taxdpd.sim.pretrain import TRAIN_SECONDS_FILE

SLOT_POINTS = (64, 128)


def children_cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def make_dataset(args) -> Path:
    root = args.dataset or args.work_dir / "data"
    if (root / "meta" / "info.json").is_file():
        return root
    if args.task == "slots":
        return write_slot_dataset(
            root,
            episodes=args.episodes,
            object_cloud_size=SLOT_POINTS[0],
            scene_cloud_size=SLOT_POINTS[1],
            yaw_range=math.pi,
            seed=0,
        )
    from lerobot_taxdpd.sim.generate import generate_dataset
    from lerobot_taxdpd.sim.tasks import get_task

    return generate_dataset(
        get_task(args.task), episodes=args.episodes, split="train", repo_id=f"local/{args.task}", root=root
    )


class HeldOut:
    """The held-out scenes of a task, their baselines, and how a checkpoint is scored on them."""

    def __init__(self, args) -> None:
        self.args = args
        if args.task == "slots":
            rng = np.random.default_rng(args.eval_seed)
            self.scenes = [make_slot_scene(rng, *SLOT_POINTS, math.pi) for _ in range(8)]
        else:
            from lerobot_taxdpd.sim.tasks import get_task
            from lerobot_taxdpd.sim.trials import make_trial

            self.task = get_task(args.task)
            self.trials = [
                make_trial(self.task, seed, "test") for seed in range(args.eval_seed, args.eval_seed + args.trials)
            ]
            self.scenes = self.trials[:8]

    def probe_clouds(self) -> tuple[torch.Tensor, torch.Tensor]:
        return (
            torch.from_numpy(np.stack([s.object_points for s in self.scenes])),
            torch.from_numpy(np.stack([s.scene_points for s in self.scenes])),
        )

    def baselines(self) -> dict:
        if self.args.task == "slots":
            return {
                "copy_start": {"rotation_error_deg": copy_start_rotation_deg(self.scenes)},
                "mean_pose": {
                    "rotation_error_deg": 90.0,
                    "note": "uniform goal yaw: any fixed orientation is 90 deg off at the median",
                },
            }
        from lerobot_taxdpd.sim.harness import evaluate
        from lerobot_taxdpd.sim.predictors import OraclePredictor

        rows = {}
        for name, orientation in (("copy_start", "start"), ("mean_pose", "mean")):
            report = evaluate(OraclePredictor(self.trials, orientation=orientation), self.trials, 1, progress=False)
            rows[name] = summarise(report)
        return rows

    def score(self, policy) -> dict:
        if self.args.task == "slots":
            row = evaluate_slot_predictor(
                policy,
                num_scenes=self.args.trials,
                num_samples=self.args.samples,
                num_object_points=SLOT_POINTS[0],
                num_scene_points=SLOT_POINTS[1],
                yaw_range=math.pi,
                seed=self.args.eval_seed,
                generator=torch.Generator().manual_seed(0),
            )
        else:
            from lerobot_taxdpd.sim.harness import evaluate

            row = summarise(evaluate(policy, self.trials, self.args.samples, progress=False))
        obj, scene = self.probe_clouds()
        period = None if self.args.task == "slots" else self.task.symmetry_period_deg  # the keyed box has none
        turns = goal_turn_response(policy, obj, scene, num_samples=2, symmetry_period_deg=period)
        return row | {f"turn_{k}_deg": v for k, v in turns.items()}


def summarise(report: dict) -> dict:
    row = {
        "success_rate": report["success"]["success_rate"],
        "ci95": [report["success"]["ci95_low"], report["success"]["ci95_high"]],
        "translation_error_mm": report["translation_error_mm"]["median"],
        "rotation_error_deg": report["rotation_error_deg"]["median"],
    }
    for key in ("gripper_translation_error_mm", "gripper_rotation_error_deg"):
        if key in report:
            row[key] = report[key]["median"]
    row |= {key: value for key, value in report.items() if key.startswith(("coverage@", "precision@"))}
    return row


def train(args) -> tuple[Path, list[str], dict]:
    """Train the recipe with a checkpoint every `--save-every` steps; the run folder, command and its cost."""
    dataset = make_dataset(args)
    run_dir = args.work_dir / "train"
    if run_dir.exists():
        shutil.rmtree(run_dir)
    flags = (
        policy_flags(args.set)
        + [
            f"--steps={args.steps}",
            f"--save_freq={args.save_every}",
            f"--log_freq={args.save_every}",
            "--num_workers=0",
            f"--seed={args.seed}",
        ]
        + ([f"--batch_size={args.batch_size}"] if args.batch_size else [])
    )
    command = train_command(dataset, f"local/{args.task}", run_dir, recipe=recipe_path(args.recipe), flags=flags)
    print(" ".join(command), flush=True)
    cpu_before = children_cpu_seconds()
    wall = run(command, log=args.work_dir / "train.log", threads=args.threads)
    cpu_minutes = (children_cpu_seconds() - cpu_before) / 60
    return run_dir, command, {"steps": args.steps, "wall_seconds": wall, "minutes": {"cpu_minutes": cpu_minutes}}


def finished_run(run_dir: Path) -> tuple[list[str], dict]:
    """The portable command, steps and training time of a finished run: from its saved config, and the wall time
    `sim pretrain` keeps beside it (`train_seconds.txt`; absent for a run made otherwise, then rows carry steps)."""
    last = run_dir / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    if not last.is_file():
        raise SystemExit(f"--run-dir {run_dir}: no finished run there ({last} is missing)")
    trained = json.loads(last.read_text())
    timing = run_dir.parent / TRAIN_SECONDS_FILE
    minutes = {"wall_minutes": float(timing.read_text()) / 60} if timing.is_file() else {}
    return [portable_train_command(trained)], {"steps": trained["steps"], "minutes": minutes}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="slots", help="'slots' or a procedural task name")
    parser.add_argument("--dataset", type=Path, default=None, help="an existing dataset (default: made in --work-dir)")
    parser.add_argument("--episodes", type=int, default=200, help="demos to generate when there is no dataset")
    parser.add_argument("--recipe", default="taxdpd_cpu")
    add_policy_overrides_argument(parser, "policy overrides, e.g. hidden_dim=64")
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--save-every", type=int, default=500)
    parser.add_argument("--batch-size", type=int, default=None)
    parser.add_argument("--seed", type=int, default=0, help="training seed")
    parser.add_argument("--threads", type=int, default=1, help="training threads (OMP_NUM_THREADS)")
    parser.add_argument("--trials", type=int, default=30, help="held-out trials (scenes) per checkpoint")
    parser.add_argument("--samples", type=int, default=10, help="K goals per trial")
    parser.add_argument("--eval-seed", type=int, default=1000)
    parser.add_argument("--work-dir", type=Path, default=None)
    parser.add_argument("--output", type=Path, default=None)
    parser.add_argument(
        "--run-dir", type=Path, default=None, help="score this finished lerobot-train run's checkpoints; no training"
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    name = args.output.stem if args.output else f"curve_{args.task}"
    args.work_dir = args.work_dir or Path("results") / name
    args.output = args.output or Path("results") / f"{name}.json"

    if args.run_dir is not None:
        run_dir, (command, training) = args.run_dir, finished_run(args.run_dir)
    else:
        run_dir, command, training = train(args)
    held_out = HeldOut(args)
    baselines = held_out.baselines()
    print(json.dumps({"baselines": baselines}), flush=True)
    rows = []
    for checkpoint in sorted((run_dir / "checkpoints").glob("[0-9]*"), key=lambda p: int(p.name)):
        step = int(checkpoint.name)
        policy = load_goal_predictor(checkpoint / "pretrained_model")
        row = {"step": step, **{key: value * step / training["steps"] for key, value in training["minutes"].items()}}
        row |= held_out.score(policy)
        rows.append(row)
        print(json.dumps(row), flush=True)
    payload = {
        "machine": machine_info(),
        "arguments": {k: str(v) for k, v in vars(args).items()},
        "train_command": " ".join(command),
        "run_dir": str(run_dir),
        "training": training,
        "baselines": baselines,
        "rows": rows,
    }
    print(f"wrote {write_json(args.output, payload)}")


if __name__ == "__main__":
    main()
