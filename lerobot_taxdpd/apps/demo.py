"""The built-in demo: shipped goal predictors, by name, placing objects in held-out simulated scenes.

For each task it loads the shipped predictor (`load_goal_predictor(task)`), builds held-out scenes
(unseen geometry), samples K goals per scene, executes the first (or, where the name ships a goal scorer,
the sample it rates highest) in pybullet with the placement controller and the physical success checks,
and writes a report per task (metrics JSON, PNGs of the sampled goals and of the Dense GMM's weights) plus a
summary. Offline, CPU, a few minutes.

    taxdpd-demo                                   # results/demo/{summary.json, <task>_eval.json, figures/}
    taxdpd-demo --tasks mug_easyrack --trials 50
    taxdpd-demo --from-scratch --tasks mug_easyrack   # generate demos and train with lerobot-train first
    taxdpd-demo --synthetic                       # the two-slot toy task, trained from scratch in minutes
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from lerobot_taxdpd.apps.slot_demo import prepare_output
from lerobot_taxdpd.reports.benchmarking import write_json
from lerobot_taxdpd.threads import add_threads_argument, configure_threads

SUMMARY = "summary.json"


def parse_args(argv: list[str]) -> argparse.Namespace:
    from lerobot_taxdpd.goal_predictors import list_goal_predictors
    from lerobot_taxdpd.sim.tasks import task_names

    shipped = [name for name in list_goal_predictors() if name in task_names()]
    parser = argparse.ArgumentParser(
        prog="taxdpd-demo", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--tasks",
        nargs="+",
        default=shipped,
        choices=task_names(),
        help=f"default: the shipped ones ({', '.join(shipped)})",
    )
    parser.add_argument("--trials", type=int, default=20, help="held-out scenes per task (default: 20)")
    parser.add_argument("--num-samples", type=int, default=10, help="goals sampled per scene, K (default: 10)")
    parser.add_argument("--figures", type=int, default=2, help="scenes drawn per task (default: 2)")
    parser.add_argument(
        "--from-scratch",
        action="store_true",
        help="train each task's predictor first (CPU recipe; about 25 min a task)",
    )
    parser.add_argument(
        "--synthetic",
        action="store_true",
        help="instead: the two-slot toy task, trained from scratch in minutes (its options: --synthetic --help)",
    )
    parser.add_argument("--output", type=Path, default=Path("results/demo"))
    add_threads_argument(parser)
    return parser.parse_args(argv)


def run_task(task_name: str, args: argparse.Namespace) -> tuple[dict, Path]:
    """The held-out report of one task and its path: the shipped predictor evaluated here, or one trained
    from scratch (the pretrain pipeline evaluates it)."""
    from lerobot_taxdpd.goal_predictors import load_goal_predictor, load_scorer, shipped_scorers
    from lerobot_taxdpd.sim.harness import evaluate
    from lerobot_taxdpd.sim.predictors import observed_as_trained
    from lerobot_taxdpd.sim.pretrain import CPU_RECIPE, pretrain
    from lerobot_taxdpd.sim.tasks import get_task
    from lerobot_taxdpd.sim.trials import make_trial

    if args.from_scratch:
        work = args.output / "train" / task_name
        pretrain(
            task_name,
            work,
            episodes=200,
            steps=None,
            recipe=CPU_RECIPE,
            trials=args.trials,
            num_samples=args.num_samples,
            ship=None,
        )
        path = work / f"{task_name}_eval.json"
        return json.loads(path.read_text()), path
    predictor = load_goal_predictor(task_name)
    task = observed_as_trained(get_task(task_name), predictor)
    trials = (make_trial(task, seed, "test") for seed in range(args.trials))
    scorer = load_scorer(task_name) if task_name in shipped_scorers() else None
    report = evaluate(
        predictor,
        trials,
        args.num_samples,
        goal_selection="scorer" if scorer is not None else "first",
        scorer=scorer,
        figures_dir=args.output / "figures",
        num_figures=args.figures,
        total=args.trials,
    )
    report["predictor"] = f"shipped:{task_name}"
    return report, write_json(args.output / f"{task_name}_eval.json", report)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--synthetic" in argv:
        from lerobot_taxdpd.apps.slot_demo import main as slot_demo

        return slot_demo([a for a in argv if a != "--synthetic"])
    args = parse_args(argv)
    configure_threads(args.threads)
    if not args.tasks:
        raise SystemExit("no shipped goal predictors in this install: pass --tasks T --from-scratch")
    prepare_output(args.output, SUMMARY)
    summary = {"trials_per_task": args.trials, "num_samples": args.num_samples, "tasks": {}}
    for task_name in args.tasks:
        print(f"{task_name}: {args.trials} held-out scenes, K = {args.num_samples}", flush=True)
        started = time.perf_counter()
        report, path = run_task(task_name, args)
        s = report["success"]
        summary["tasks"][task_name] = {
            "predictor": report["predictor"],
            "executed_sample": report["goal_selection"],
            "success_rate": s["success_rate"],
            "ci95": [s["ci95_low"], s["ci95_high"]],
            "translation_error_mm": report["translation_error_mm"]["median"],
            "rotation_error_deg": report["rotation_error_deg"]["median"],
            "seconds": time.perf_counter() - started,
            "report": str(path),
        }
        print(
            f"  success {s['success_rate']:.0%} (95% CI {s['ci95_low']:.0%}-{s['ci95_high']:.0%}) executing the "
            f"{report['goal_selection']} sample, median errors "
            f"{report['translation_error_mm']['median']:.1f} mm / {report['rotation_error_deg']['median']:.1f} deg",
            flush=True,
        )
    print(json.dumps(summary["tasks"], indent=2))
    print(f"summary: {write_json(args.output / SUMMARY, summary)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
