"""Command line of the procedural benchmarks: `python -m lerobot_taxdpd.sim {generate,eval} --task T ...`

    generate  scripted demonstrations -> a LeRobot v3.0 goal-prediction dataset
    eval      a goal predictor on held-out trials -> JSON report and PNG figures
    pretrain  generate + lerobot-train + eval, then save the checkpoint with its metrics (a shipped predictor)

`--task cloth_hang` is handed, with the whole command line, to the cloth task's own command line.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from lerobot_taxdpd.sim.splits import SPLITS

CLOTH_TASK = "cloth_hang"


def _requested_task(argv: list[str]) -> str | None:
    for i, arg in enumerate(argv):
        if arg == "--task" and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith("--task="):
            return arg.split("=", 1)[1]
    return None


def build_parser() -> argparse.ArgumentParser:
    from lerobot_taxdpd.sim.tasks import task_names

    tasks = [*task_names(), CLOTH_TASK]
    parser = argparse.ArgumentParser(prog="python -m lerobot_taxdpd.sim", description=__doc__.split("\n\n")[0])
    verbs = parser.add_subparsers(dest="verb", required=True)

    generate = verbs.add_parser("generate", help="write scripted demonstrations as a LeRobot dataset")
    generate.add_argument("--task", required=True, choices=tasks)
    generate.add_argument("--episodes", type=int, required=True, help="number of demonstrations (one episode each)")
    generate.add_argument("--split", choices=SPLITS, default="train", help="geometry split (default: train)")
    generate.add_argument("--repo-id", required=True, help="dataset repo id, e.g. me/mug_easyrack")
    generate.add_argument("--root", required=True, type=Path, help="output folder; must not exist unless --overwrite")
    generate.add_argument("--seed", type=int, default=0, help="episode i uses scene seed SEED + i (default: 0)")
    generate.add_argument("--frames-per-episode", type=int, default=2, help="observations of each demo (>= 2)")
    generate.add_argument("--overwrite", action="store_true", help="replace an existing dataset at --root, atomically")

    evaluate = verbs.add_parser("eval", help="evaluate a goal predictor on held-out trials")
    evaluate.add_argument("--task", required=True, choices=tasks)
    source = evaluate.add_mutually_exclusive_group(required=True)
    source.add_argument(
        "--policy.path",
        dest="policy_path",
        help="TAX-DPD goal predictor: a shipped name, a checkpoint folder or a Hub id",
    )
    source.add_argument(
        "--predictor",
        help="'oracle' (ground truth, checks the benchmark itself) or 'package.module:factory' returning an "
        "object with sample_goals(object_points, scene_points, num_samples)",
    )
    evaluate.add_argument("--trials", type=int, default=100, help="number of trials (default: 100)")
    evaluate.add_argument("--num-samples", type=int, default=10, help="goals sampled per trial, K (default: 10)")
    evaluate.add_argument("--seed", type=int, default=0, help="trial i uses scene seed SEED + i (default: 0)")
    evaluate.add_argument("--split", choices=SPLITS, default="test", help="geometry split (default: test, held out)")
    evaluate.add_argument("--output", type=Path, default=Path("outputs/sim_eval"), help="folder for the JSON and PNGs")
    evaluate.add_argument("--figures", type=int, default=3, help="trials to draw (default: 3)")
    evaluate.add_argument("--oracle-error-mm", type=float, default=0.0, help="oracle only: translation error to add")
    evaluate.add_argument("--oracle-error-deg", type=float, default=0.0, help="oracle only: rotation error to add")

    pretrain = verbs.add_parser(
        "pretrain",
        help="demos, lerobot-train, held-out eval, and a packaged checkpoint",
        epilog="Any --policy.<field>=<value> flag (e.g. --policy.use_gmm=false) and --seed=<n> are passed on "
        "to lerobot-train.",
    )
    pretrain.add_argument("--task", required=True, choices=task_names())
    pretrain.add_argument("--episodes", type=int, default=200, help="training demonstrations (default: 200)")
    pretrain.add_argument("--steps", type=int, default=None, help="training steps (default: the config's)")
    pretrain.add_argument(
        "--config", default=None, help="a shipped recipe name or a lerobot-train config file (default: taxdpd_cpu)"
    )
    pretrain.add_argument("--trials", type=int, default=100, help="held-out evaluation trials (default: 100)")
    pretrain.add_argument("--num-samples", type=int, default=10, help="goals sampled per trial, K (default: 10)")
    pretrain.add_argument("--output", type=Path, default=None, help="work folder (default: results/pretrain/<task>)")
    pretrain.add_argument("--ship", type=Path, default=None, help="save the evaluated checkpoint as <SHIP>/<task>")
    pretrain.add_argument(
        "--dataset",
        type=Path,
        default=None,
        help="demonstrations folder, generated if missing (default: <output>/data)",
    )
    return parser


def _pretrain(args: argparse.Namespace, overrides: list[str]) -> int:
    from lerobot_taxdpd.sim.pretrain import CPU_RECIPE, pretrain

    pretrain(
        args.task,
        args.output or Path("results/pretrain") / args.task,
        episodes=args.episodes,
        steps=args.steps,
        recipe=args.config or CPU_RECIPE,
        trials=args.trials,
        num_samples=args.num_samples,
        ship=args.ship,
        dataset=args.dataset,
        overrides=overrides,
    )
    return 0


def _generate(args: argparse.Namespace, argv: list[str]) -> int:
    from lerobot_taxdpd.sim.generate import generate_dataset
    from lerobot_taxdpd.sim.tasks import get_task

    root = generate_dataset(
        get_task(args.task),
        episodes=args.episodes,
        split=args.split,
        repo_id=args.repo_id,
        root=args.root,
        seed=args.seed,
        frames_per_episode=args.frames_per_episode,
        overwrite=args.overwrite,
        command="python -m lerobot_taxdpd.sim " + shlex.join(argv),
    )
    print(f"wrote {args.episodes} {args.task} demonstrations ({args.split} geometry) to {root}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from lerobot_taxdpd.goal_predictors import load_goal_predictor
    from lerobot_taxdpd.reports.benchmarking import write_json
    from lerobot_taxdpd.sim.harness import evaluate
    from lerobot_taxdpd.sim.predictors import OraclePredictor, load_predictor
    from lerobot_taxdpd.sim.tasks import get_task
    from lerobot_taxdpd.sim.trials import make_trial

    if args.trials < 1:
        raise ValueError(f"--trials: must be at least 1, got {args.trials}")
    task = get_task(args.task)
    seeds = range(args.seed, args.seed + args.trials)
    oracle = args.predictor == "oracle"
    if not oracle and (args.oracle_error_mm or args.oracle_error_deg):
        raise ValueError("--oracle-error-mm/--oracle-error-deg only apply to --predictor oracle")
    if oracle:
        trials = [make_trial(task, seed, args.split) for seed in seeds]
        predictor = OraclePredictor(trials, args.oracle_error_mm / 1000, args.oracle_error_deg, seed=args.seed)
    elif args.policy_path:
        try:
            predictor = load_goal_predictor(args.policy_path)
        except (OSError, ValueError) as error:
            raise ValueError(
                f"--policy.path {args.policy_path}: not a loadable TAX-DPD checkpoint ({error})"
            ) from error
    else:
        predictor = load_predictor(args.predictor)
    if not oracle:
        trials = (make_trial(task, seed, args.split) for seed in seeds)
    report = evaluate(
        predictor,
        trials,
        args.num_samples,
        figures_dir=args.output / "figures",
        num_figures=args.figures,
        total=args.trials,
    )
    report["predictor"] = args.policy_path or args.predictor
    path = write_json(args.output / f"{task.name}_eval.json", report)
    s = report["success"]
    print(
        f"{task.name}: success {s['success_rate']:.1%} (95% CI {s['ci95_low']:.1%}-{s['ci95_high']:.1%}) over "
        f"{s['trials']} trials; median translation error {report['translation_error_mm']['median']:.2f} mm, "
        f"rotation error {report['rotation_error_deg']['median']:.2f} deg; report: {path}"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if _requested_task(argv) == CLOTH_TASK:
        from lerobot_taxdpd.sim.cloth.cli import main as cloth_main

        return cloth_main(argv)
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    overrides = [
        arg for arg in unknown if args.verb == "pretrain" and arg.startswith(("--policy.", "--seed=")) and "=" in arg
    ]
    if len(overrides) < len(unknown):
        parser.error(f"unrecognized arguments: {' '.join(arg for arg in unknown if arg not in overrides)}")
    try:
        verbs = {
            "generate": lambda: _generate(args, argv),
            "eval": lambda: _evaluate(args),
            "pretrain": lambda: _pretrain(args, overrides),
        }
        return verbs[args.verb]()
    except (ValueError, FileExistsError, FileNotFoundError, TypeError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
