"""Goal-sampling latency and one simulated evaluation trial with torch's default thread count against fewer
threads, with and without the other cores kept busy: the measurement behind the package's default of one
thread (`lerobot_taxdpd.threads`).

For each load case ("as found": whatever the machine is doing, its load average recorded; "cores busy":
plus `--busy` processes spinning, by default all cores but one) and each thread count (torch's default at
start-up, then 1): `sample_goals` of a shipped predictor on a held-out scene at K = 2 and K = 10, and one
`sim eval` trial (K goals, RANSAC-SVD, pybullet execution) on a pre-built scene; medians of `--repeats`.
On an idle machine, "as found" is the idle case. Prints the machine, threads and config, writes JSON.

    python benchmarks/threads.py                       # results/threads.json
    python benchmarks/threads.py --loads busy --repeats 3 --output results/threads_busy.json
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import torch

from lerobot_taxdpd.goal_predictors import load_goal_predictor
from lerobot_taxdpd.reports.benchmarking import machine_info, timed, write_json
from lerobot_taxdpd.sim.harness import evaluate
from lerobot_taxdpd.sim.tasks import get_task
from lerobot_taxdpd.sim.trials import make_trial

TORCH_DEFAULT_THREADS = torch.get_num_threads()  # read before anything changes it
LOADS = ("as_found", "busy")


@contextlib.contextmanager
def busy_cores(count: int) -> Iterator[None]:
    """`count` processes spinning on a core each while the block runs."""
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]
    try:
        yield
    finally:
        for spinner in spinners:
            spinner.kill()
            spinner.wait()


def measure(predictor, trial, args: argparse.Namespace, threads: int) -> dict:
    torch.set_num_threads(threads)
    object_points = torch.from_numpy(trial.object_points)[None]
    scene_points = torch.from_numpy(trial.scene_points)[None]
    result: dict = {"threads": threads}
    for k in args.num_samples:
        median, times = timed(lambda k=k: predictor.sample_goals(object_points, scene_points, k), args.repeats)
        result[f"sample_goals_k{k}_s"] = {"median": median, "all": times}
    k = max(args.num_samples)
    median, times = timed(lambda: evaluate(predictor, [trial], k, progress=False), args.repeats)
    result[f"eval_trial_k{k}_s"] = {"median": median, "all": times}
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--predictor", default="mug_easyrack", help="a shipped goal predictor (its task is used)")
    parser.add_argument("--thread-counts", type=int, nargs="+", default=sorted({TORCH_DEFAULT_THREADS, 1})[::-1])
    parser.add_argument("--loads", nargs="+", choices=LOADS, default=list(LOADS))
    parser.add_argument("--busy", type=int, default=max(1, (os.cpu_count() or 2) - 1), help="spinning processes")
    parser.add_argument("--num-samples", type=int, nargs="+", default=[2, 10], help="K values of sample_goals")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0, help="held-out scene seed")
    parser.add_argument("--output", type=Path, default=Path("results/threads.json"))
    args = parser.parse_args(argv)

    predictor = load_goal_predictor(args.predictor)
    trial = make_trial(get_task(predictor.metrics.get("task", args.predictor)), args.seed, "test")
    config = predictor.config
    print(
        f"predictor {args.predictor}: hidden {config.hidden_dim}, {config.num_blocks} blocks, network sees "
        f"{config.num_object_points}/{config.num_scene_points} points of {trial.object_points.shape[0]}/"
        f"{trial.scene_points.shape[0]}, {config.sampler} {config.num_inference_steps} steps; torch's default "
        f"threads {TORCH_DEFAULT_THREADS}"
    )
    cases = []
    for load in args.loads:
        with busy_cores(args.busy if load == "busy" else 0):
            for threads in args.thread_counts:
                result = {"load": load, "busy_processes": args.busy if load == "busy" else 0}
                result.update(measure(predictor, trial, args, threads))
                result["machine"] = machine_info()
                cases.append(result)
                figures = ", ".join(f"{key} {value['median']:.3f}" for key, value in result.items() if key[-2:] == "_s")
                print(
                    f"{load:>8}, {threads} thread(s), load average {result['machine']['load_average_1min']:.1f}: "
                    f"{figures}",
                    flush=True,
                )
    payload = {
        "command": "python " + " ".join(sys.argv),
        "predictor": args.predictor,
        "scene": {"task": trial.task.name, "seed": args.seed, "split": "test"},
        "torch_default_threads": TORCH_DEFAULT_THREADS,
        "cases": cases,
    }
    print(f"written to {write_json(args.output, payload)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
