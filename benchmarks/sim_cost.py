"""Seconds per trial of each simulation benchmark, split into its two halves.

A trial is: sample a held-out scene, find its reachable goals and render the observation (two or more
depth cameras, TinyRenderer); then execute one placement (controller, settling, checks and the
upside-down test). The predictor's own time is not included: it depends on the model, and the harness
reports it separately. Ground-truth goals are executed, so the figures are those of a successful
placement. Also timed: one dataset episode (a demo observed twice). Medians over the trials; the
machine, its load and the thread count are printed beside them and written to the JSON.

    python benchmarks/sim_cost.py                      # results/sim_cost.json
    python benchmarks/sim_cost.py --trials 5 --tasks mug_easyrack
"""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
import sys
import time
from pathlib import Path

from tqdm import tqdm

from lerobot_taxdpd.reports.benchmarking import machine_info, write_json
from lerobot_taxdpd.sim.tasks import get_task, task_names
from lerobot_taxdpd.sim.trials import execute, make_trial


def _timed(run, *args, **kwargs) -> tuple[float, object]:
    started = time.perf_counter()
    result = run(*args, **kwargs)
    return time.perf_counter() - started, result


def measure(task_name: str, trials: int, seed: int) -> dict:
    task = get_task(task_name)
    observe, place, episode = [], [], []
    for i in tqdm(range(trials), desc=task_name):
        seconds, trial = _timed(make_trial, task, seed + i, "test")
        observe.append(seconds)
        place.append(_timed(execute, trial, trial.goal_transform)[0])
        episode.append(_timed(make_trial, task, seed + i, "train", num_views=2)[0])
    per_trial = statistics.median([a + b for a, b in zip(observe, place, strict=True)])
    return {
        "trials": trials,
        "scene_and_observation_s": statistics.median(observe),
        "placement_and_checks_s": statistics.median(place),
        "seconds_per_trial": per_trial,
        "minutes_per_100_trials": per_trial * 100 / 60,
        "dataset_episode_2_frames_s": statistics.median(episode),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="+", default=task_names(), choices=task_names())
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", type=Path, default=Path("results/sim_cost.json"))
    args = parser.parse_args()
    config = {
        "trials per task": args.trials,
        "seed": args.seed,
        "renderer": "pybullet TinyRenderer",
        "statistic": "median",
    }
    print(f"machine: {json.dumps(machine_info())}\nconfig: {json.dumps(config)}")
    print(f"{'task':26s} {'observe s':>10s} {'place s':>9s} {'trial s':>9s} {'100 trials':>11s} {'episode s':>10s}")
    results = {}
    for name in args.tasks:
        r = results[name] = measure(name, args.trials, args.seed)
        print(
            f"{name:26s} {r['scene_and_observation_s']:>10.3f} {r['placement_and_checks_s']:>9.3f} "
            f"{r['seconds_per_trial']:>9.3f} {r['minutes_per_100_trials']:>7.1f} min "
            f"{r['dataset_episode_2_frames_s']:>10.3f}",
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
