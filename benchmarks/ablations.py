"""The ablation table: every switch of the paper's ablation study, trained and evaluated under one budget.

Each (task, variant) is one `python -m lerobot_taxdpd.sim pretrain` run with the same demonstrations (shared
per task), the same recipe (the shipped `taxdpd_ablation` by default: hidden 32, 2 DiT blocks, 64/128
points seen by the network, batch 16, 600 steps; about 6 minutes a run on one core of a 2-core CPU), and
the same 100 held-out trials with K = 10 goals. Finished runs are reused, so an interrupted table resumes
where it stopped.

    python benchmarks/ablations.py                       # results/ablations.{json,md}, runs in results/ablations/
    python benchmarks/ablations.py --jobs 2              # two runs at a time, one torch thread each
    python benchmarks/ablations.py --tasks insert_ssd --variants full   # any task, any subset of variants
    python benchmarks/ablations.py --report-only         # the table of whatever has finished so far

At a recipe that places (the README's table): the CPU recipe with the task's own flags, on demonstrations
already made by `sim pretrain` (the same seeds `generate` uses; link them to OUTPUT/TASK/data to reuse them):

    python benchmarks/ablations.py --config taxdpd_cpu --steps 2000 --episodes 1000 --tasks mug_medrack \
        --set frame_noise_std=0.3 --output results/ablations_cpu
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from lerobot_taxdpd.maths.metrics import paired_difference
from lerobot_taxdpd.recipes import add_policy_overrides_argument, policy_flags, run
from lerobot_taxdpd.reports.benchmarking import machine_info, write_json
from lerobot_taxdpd.sim.tasks import task_names
from lerobot_taxdpd.threads import add_threads_argument, configure_threads

#: Variant -> (the paper's ablation row, lerobot-train flags); the flags are explained in docs/taxdpd.md.
VARIANTS: dict[str, tuple[str, list[str]]] = {
    "full": ("TAX-DPD", []),
    "no_disentangled": ("w/o disentangled point diffusion", ["--policy.disentangled=false"]),
    "mlp_encoder": ("w/ MLP encodings", ["--policy.encoder=mlp"]),
    "no_gmm": ("w/o GMM", ["--policy.use_gmm=false"]),
    "no_reconstruction_embedding": ("w/o recon. embedding", ["--policy.use_reconstruction_embedding=false"]),
    "no_rotation_noise": ("w/o rot. noise", ["--policy.use_rotation_noise=false"]),
    "no_deformation_embedding": ("w/o deform. embedding", ["--policy.use_deformation_embedding=false"]),
    "se3_diffusion": ("w/ SE(3) diffusion", ["--policy.local_diffusion=se3"]),
    "tax3d_style": (
        "TAX3D",
        [
            "--policy.use_gmm=false",
            "--policy.disentangled=false",
            "--policy.use_reconstruction_embedding=false",
            "--policy.use_deformation_embedding=false",
        ],
    ),
    # not a switch: the full model trained again from another seed, to show how much of a difference the
    # training run alone makes (the intervals above cover the held-out scenes, not the training seed)
    "full_seed1": ("TAX-DPD, training seed 1", ["--seed=1"]),
}
#: The paper's success rates (its Table: ablations on RPDiff tasks) for the tasks it reports.
PAPER = {
    "mug_medrack": {
        "full": 0.97, "no_disentangled": 0.74, "mlp_encoder": 0.84, "no_gmm": 0.87,
        "no_reconstruction_embedding": 0.91, "no_rotation_noise": 0.85, "no_deformation_embedding": 0.94,
        "se3_diffusion": 0.92, "tax3d_style": 0.46,
    },
    "book_shelf": {
        "full": 0.99, "no_disentangled": 0.53, "mlp_encoder": 0.61, "no_gmm": 0.75,
        "no_reconstruction_embedding": 0.78, "no_rotation_noise": 0.96, "no_deformation_embedding": 0.95,
        "se3_diffusion": 0.96, "tax3d_style": 0.38,
    },
}
DEFAULT_TASKS = ["mug_medrack", "book_shelf", "insert_waterproof"]


def run_command(task: str, variant: str, args: argparse.Namespace) -> list[str]:
    """The `sim pretrain` command of one cell, as recorded in the table and run by `recipes.run`."""
    work = args.output / task
    return [
        "python", "-m", "lerobot_taxdpd.sim", "pretrain", f"--task={task}", f"--config={args.config}",
        f"--episodes={args.episodes}", f"--trials={args.trials}", f"--num-samples={args.num_samples}",
        f"--dataset={work / 'data'}", f"--output={work / variant}",
        *([f"--steps={args.steps}"] if args.steps else []), *policy_flags(args.set), *VARIANTS[variant][1],
    ]



def generate_data(task: str, args: argparse.Namespace, threads: int) -> str | None:
    """The task's shared demonstrations unless they exist; returns why generating them failed, if it did."""
    data = args.output / task / "data"
    if (data / "meta" / "info.json").is_file():
        return None
    command = [
        "python", "-m", "lerobot_taxdpd.sim", "generate", f"--task={task}", f"--episodes={args.episodes}",
        "--split=train", f"--repo-id=local/{task}", f"--root={data}",
    ]
    log = args.output / task / "generate.log"
    try:
        run(command, log=log, threads=threads)
    except subprocess.CalledProcessError as error:
        return f"{task}: generating demonstrations failed with exit status {error.returncode}, see {log}"
    return None


def train_and_evaluate(task: str, variant: str, args: argparse.Namespace, threads: int) -> str | None:
    """Run one cell of the table unless it is already there; returns why it failed, if it did."""
    folder = args.output / task / variant
    if (folder / "metrics.json").is_file():
        return None
    started = time.perf_counter()
    log = folder.with_suffix(".log")
    try:
        run(run_command(task, variant, args), log=log, threads=threads)
    except subprocess.CalledProcessError as error:
        return f"{task} / {variant}: exit status {error.returncode}, see {log}"
    print(f"{task} / {variant}: {(time.perf_counter() - started) / 60:.1f} min", flush=True)
    return None


def per_trial_wta_rmse(task: str, variant: str, args: argparse.Namespace) -> np.ndarray:
    """Winner-take-all RMSE (mm) of every held-out trial, in seed order (every variant sees the same seeds)."""
    report = json.loads((args.output / task / variant / f"{task}_eval.json").read_text())
    return np.array(
        [trial["winner_take_all_rmse_mm"] for trial in sorted(report["per_trial"], key=lambda t: t["seed"])]
    )


def table_row(task: str, variant: str, args: argparse.Namespace, finished: set[tuple[str, str]]) -> dict:
    metrics = json.loads((args.output / task / variant / "metrics.json").read_text())
    success = metrics["success"]
    coverage = next((key for key in metrics if key.startswith("coverage@")), None)
    versus_full = None
    if variant != "full" and (task, "full") in finished:
        mean, low, high = paired_difference(
            per_trial_wta_rmse(task, variant, args), per_trial_wta_rmse(task, "full", args)
        )
        versus_full = {"mean_mm": mean, "ci95_mm": [low, high]}
    return {
        "task": task,
        "variant": variant,
        "paper_row": VARIANTS[variant][0],
        "success_rate": success["success_rate"],
        "success_ci95": [success["ci95_low"], success["ci95_high"]],
        "translation_error_mm": metrics["translation_error_mm"]["median"],
        "rotation_error_deg": metrics["rotation_error_deg"]["median"],
        "winner_take_all_rmse_mm": metrics["winner_take_all_rmse_mm"]["mean"],
        "winner_take_all_rmse_vs_full": versus_full,
        "coverage": metrics[coverage] if coverage else None,
        "precision": metrics[coverage.replace("coverage", "precision")] if coverage else None,
        "coverage_threshold_mm": metrics.get("coverage_threshold_mm"),
        "paper_success_rate": PAPER.get(task, {}).get(variant),
        "train_seconds": metrics["train_seconds"],
        "command": " ".join(str(part) for part in run_command(task, variant, args)),
    }


def markdown(rows: list[dict]) -> str:
    lines = [
        "| task | variant | success (95% CI) | paper | median translation / rotation error | mean WTA RMSE "
        "| WTA RMSE minus full's, paired (95% CI) | coverage / precision |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        low, high = row["success_ci95"]
        paper = f"{row['paper_success_rate']:.2f}" if row["paper_success_rate"] is not None else "-"
        cover = "-" if row["coverage"] is None else f"{row['coverage']:.2f} / {row['precision']:.2f}"
        versus = row["winner_take_all_rmse_vs_full"]
        versus = (
            "-" if versus is None else "{:+.1f} mm ({:+.1f} to {:+.1f})".format(versus["mean_mm"], *versus["ci95_mm"])
        )
        lines.append(
            f"| {row['task']} | {row['paper_row']} (`{row['variant']}`) | "
            f"{row['success_rate']:.0%} ({low:.0%}-{high:.0%}) | {paper} | "
            f"{row['translation_error_mm']:.1f} mm / {row['rotation_error_deg']:.1f} deg | "
            f"{row['winner_take_all_rmse_mm']:.1f} mm | {versus} | {cover} |"
        )
    return "\n".join(lines) + "\n"


def summary_markdown(rows: list[dict]) -> str:
    """One line a variant, one column a task: success and the paired WTA RMSE change, paper's success beside;
    variants ranked by their mean success over the tasks they ran."""
    tasks = list(dict.fromkeys(row["task"] for row in rows))
    paper_tasks = [task for task in tasks if task in PAPER]
    cells = {(row["task"], row["variant"]): row for row in rows}
    header = ["variant", *(f"{task}: success, WTA RMSE (paired change)" for task in tasks)]
    header += [f"paper {task}" for task in paper_tasks]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    variants = list(dict.fromkeys(row["variant"] for row in rows))
    mean_success = {v: np.mean([row["success_rate"] for row in rows if row["variant"] == v]) for v in variants}
    for variant in sorted(variants, key=lambda v: -mean_success[v]):
        line = [f"{VARIANTS[variant][0]} (`{variant}`)"]
        for task in tasks:
            row = cells.get((task, variant))
            if row is None:
                line.append("-")
                continue
            low, high = row["success_ci95"]
            versus = row["winner_take_all_rmse_vs_full"]
            change = (
                f"{row['winner_take_all_rmse_mm']:.1f} mm"
                if versus is None
                else "{:+.1f} mm ({:+.1f} to {:+.1f})".format(versus["mean_mm"], *versus["ci95_mm"])
            )
            line.append(f"{row['success_rate']:.0%} ({low:.0%}-{high:.0%}), {change}")
        line += [f"{PAPER[task][variant]:.2f}" if variant in PAPER[task] else "-" for task in paper_tasks]
        lines.append("| " + " | ".join(line) + " |")
    return "\n".join(lines) + "\n"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="+", default=DEFAULT_TASKS, choices=task_names())
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument(
        "--config", default="taxdpd_ablation", help="a shipped recipe name or a config file (default: taxdpd_ablation)"
    )
    parser.add_argument("--steps", type=int, default=None, help="training steps (default: the config's)")
    add_policy_overrides_argument(
        parser, "policy config fields for every cell (before its switch), e.g. a task's recipe: frame_noise_std=0.3"
    )
    parser.add_argument("--episodes", type=int, default=200, help="demonstrations per task (default: 200)")
    parser.add_argument("--trials", type=int, default=100, help="held-out trials per run (default: 100)")
    parser.add_argument("--num-samples", type=int, default=10, help="K goals per trial (default: 10)")
    parser.add_argument("--jobs", type=int, default=1, help="runs at the same time (default: 1)")
    parser.add_argument("--output", type=Path, default=Path("results/ablations"))
    add_threads_argument(parser)  # per run
    parser.add_argument(
        "--report-only", action="store_true", help="write the table from the finished runs, train nothing"
    )
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    threads = configure_threads(args.threads)
    started = time.perf_counter()
    # variant-major order: an interrupted table still has every task for the variants it reached
    jobs = [(task, variant) for variant in args.variants for task in args.tasks]
    failures = []
    if not args.report_only:
        with ThreadPoolExecutor(args.jobs) as pool:  # the work itself happens in child processes
            failures = [
                error for error in pool.map(lambda task: generate_data(task, args, threads), args.tasks) if error
            ]
            ready = [job for job in jobs if not any(error.startswith(f"{job[0]}:") for error in failures)]
            failures += [
                error for error in pool.map(lambda job: train_and_evaluate(*job, args, threads), ready) if error
            ]
    finished = {job for job in jobs if (args.output / job[0] / job[1] / "metrics.json").is_file()}
    rows = [
        table_row(task, variant, args, finished)
        for task in args.tasks
        for variant in args.variants
        if (task, variant) in finished
    ]
    machine = machine_info()
    machine["torch_threads"] = threads
    payload = {
        "machine": machine,
        "config": str(args.config),
        "overrides": args.set,
        "jobs": args.jobs,
        "rows": rows,
        "failures": failures,
        "wall_seconds": time.perf_counter() - started,
    }
    write_json(args.output.with_suffix(".json"), payload)
    tables = summary_markdown(rows) + "\n" + markdown(rows)
    args.output.with_suffix(".md").write_text(tables)
    print(tables)
    for failure in failures:
        print(f"failed: {failure}", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
