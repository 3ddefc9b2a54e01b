"""Calibration of the simulation benchmarks' success checks: do they accept what is right and reject
what is wrong?

For every task, on held-out (test) geometry: the demonstrator's ground-truth goals must succeed
(>= 98%), and goals off by the task's tolerance-scale error must fail most of the time. Errors are rigid
motions of exactly the given size (random direction, random axis through the goal cloud's centroid),
applied to the whole goal, then to translation or rotation alone. Everything runs through the
evaluation harness, as a model's samples would: clouds -> RANSAC-SVD pose -> controller -> checks.

    python benchmarks/sim_calibration.py                          # results/sim_calibration.json
    python benchmarks/sim_calibration.py --tasks insert_ssd --trials 20
    python benchmarks/sim_calibration.py --tasks can_cabinet --error 20 15   # 2 cm / 15 deg
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

from tqdm import tqdm

from lerobot_taxdpd.reports.benchmarking import machine_info, write_json
from lerobot_taxdpd.sim.harness import evaluate
from lerobot_taxdpd.sim.predictors import OraclePredictor
from lerobot_taxdpd.sim.tasks import get_task, task_names
from lerobot_taxdpd.sim.trials import make_trial


def calibrate(task_name: str, trials: int, seed: int, error: tuple[float, float] | None = None) -> dict:
    """Success of exact goals and failure of goals off by `error` (metres, degrees; default: the task's)."""
    task = get_task(task_name)
    started = time.perf_counter()
    scenes = [make_trial(task, seed + i, "test") for i in tqdm(range(trials), desc=f"{task_name} scenes")]
    translation, angle = error or task.perturbation
    errors = {
        "ground_truth": (0.0, 0.0),
        "perturbed": (translation, angle),
        "translation_only": (translation, 0.0),
        "rotation_only": (0.0, angle),
    }
    result = {}
    for label, (metres, degrees) in errors.items():
        report = evaluate(OraclePredictor(scenes, metres, degrees, seed=seed), scenes, 1, progress=False)
        success = report["success"]
        result[label] = {
            "translation_mm": metres * 1000,
            "rotation_deg": degrees,
            "success_rate": success["success_rate"],
            "success_ci95": [success["ci95_low"], success["ci95_high"]],
            "failure_rate": 1.0 - success["success_rate"],
            "failures": report["failures"],
        }
    result["trials"] = trials
    result["seconds"] = time.perf_counter() - started
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="+", default=task_names(), choices=task_names())
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0, help="trials use test-split scene seeds SEED..SEED+N-1")
    parser.add_argument("--output", type=Path, default=Path("results/sim_calibration.json"))
    parser.add_argument("--error", nargs=2, type=float, metavar=("MM", "DEG"), help="one error size for every task")
    args = parser.parse_args()
    error = (args.error[0] / 1000, args.error[1]) if args.error else None
    config = {
        "trials": args.trials,
        "seed": args.seed,
        "split": "test",
        "samples executed": 1,
        "error": args.error or "per task",
    }
    print(f"machine: {json.dumps(machine_info())}\nconfig: {json.dumps(config)}")
    header = ("task", "GT success", "perturbation", "failure", "transl. only", "rot. only")
    print("{:26s} {:>12s} {:>16s} {:>8s} {:>12s} {:>10s}".format(*header))
    results = {}
    for name in args.tasks:
        r = results[name] = calibrate(name, args.trials, args.seed, error)
        p = r["perturbed"]
        error_size = f"{p['translation_mm']:.0f} mm {p['rotation_deg']:.0f} deg"
        print(
            f"{name:26s} {r['ground_truth']['success_rate']:>12.1%} {error_size:>16s} {p['failure_rate']:>8.1%} "
            f"{r['translation_only']['failure_rate']:>12.1%} {r['rotation_only']['failure_rate']:>10.1%}",
            flush=True,
        )
    payload = {
        "command": shlex.join(["python", *sys.argv]),
        "machine": machine_info(),
        "config": config,
        "tasks": results,
    }
    print(f"wrote {write_json(args.output, payload)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
