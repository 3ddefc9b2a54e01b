"""Command line of the `cloth_hang` task, reached through `python -m lerobot_taxdpd.sim {generate,eval}
--task cloth_hang ...` (or `python -m lerobot_taxdpd.sim.cloth ...`).

    generate  expert demonstrations -> the goal-prediction and/or gc_dp3 policy dataset
    eval      held-out trials: goal-predictor coverage/precision, gc_dp3 success with predicted and
              ground-truth goals, seconds per trial, PNGs
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from lerobot_taxdpd.data.schema import DEFAULT_POINT_COUNTS
from lerobot_taxdpd.sim.cloth.datasets import DATASET_KINDS
from lerobot_taxdpd.sim.cloth.scene import SPLITS

TASK = "cloth_hang"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m lerobot_taxdpd.sim", description=__doc__.split("\n\n")[0])
    verbs = parser.add_subparsers(dest="verb", required=True)

    generate = verbs.add_parser("generate", help="write expert demonstrations as LeRobot datasets")
    _common(generate, default_split="train")
    generate.add_argument("--episodes", type=int, required=True, help="scene seeds tried (failed demos are skipped)")
    generate.add_argument(
        "--repo-id", required=True, help="dataset repo id, e.g. me/cloth_hang (suffixed _goal/_policy for both)"
    )
    generate.add_argument(
        "--root", type=Path, required=True, help="output folder (for both: ROOT/goal and ROOT/policy)"
    )
    generate.add_argument("--dataset", choices=DATASET_KINDS, default="both", help="which dataset(s) to write")
    generate.add_argument("--views", type=int, default=4, help="point samplings (frames) per goal-prediction episode")
    generate.add_argument(
        "--object-cloud-size", type=int, default=DEFAULT_POINT_COUNTS[TASK][0], help="cloth points stored per frame"
    )
    generate.add_argument(
        "--scene-cloud-size", type=int, default=DEFAULT_POINT_COUNTS[TASK][1], help="hanger points stored per frame"
    )
    generate.add_argument("--overwrite", action="store_true", help="replace an existing dataset (only once complete)")

    evaluate = verbs.add_parser("eval", help="evaluate goal predictor and gc_dp3 on held-out scenes")
    _common(evaluate, default_split="test")
    evaluate.add_argument("--trials", type=int, default=100)
    evaluate.add_argument("--policy.path", dest="policy_path", help="gc_dp3 checkpoint (pretrained_model folder)")
    evaluate.add_argument(
        "--goal-policy.path",
        dest="goal_policy_path",
        help="taxdpd goal predictor: shipped name, checkpoint folder or Hub id",
    )
    evaluate.add_argument("--ground-truth-goals", action="store_true", help="also run gc_dp3 on a ground-truth goal")
    evaluate.add_argument(
        "--num-samples", dest="num_goal_samples", type=int, default=10, help="K goals sampled per scene"
    )
    evaluate.add_argument("--goal-threshold", type=float, default=0.5, help="RMSE (m) for coverage@K / precision@K")
    evaluate.add_argument("--plots", type=int, default=5, help="PNGs for the first N trials")
    evaluate.add_argument("--output", type=Path, default=Path("outputs/eval/cloth_hang"))
    evaluate.add_argument("--device", default="cpu")
    evaluate.add_argument(
        "--ship", type=Path, default=None, help="save the goal predictor with these results as <SHIP>/cloth_hang"
    )
    return parser


def _common(parser: argparse.ArgumentParser, default_split: str) -> None:
    parser.add_argument("--task", required=True, choices=[TASK])
    parser.add_argument("--split", choices=SPLITS, default=default_split)
    parser.add_argument("--seed", type=int, default=0, help="first scene seed")
    parser.add_argument("--workers", type=int, default=1, help="parallel simulation processes")


def main(argv: list[str] | None = None) -> int:
    """Entry point; `argv` starts with the verb (generate | eval)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    if args.workers < 1:
        raise SystemExit(f"--workers: must be at least 1, got {args.workers}")
    if args.verb == "generate":
        from lerobot_taxdpd.sim.cloth.datasets import generate

        summary = generate(
            split=args.split,
            seed=args.seed,
            episodes=args.episodes,
            root=args.root,
            repo_id=args.repo_id,
            kind=args.dataset,
            views=args.views,
            object_cloud_size=args.object_cloud_size,
            scene_cloud_size=args.scene_cloud_size,
            workers=args.workers,
            overwrite=args.overwrite,
            command="python -m lerobot_taxdpd.sim " + shlex.join(argv),
        )
        print(json.dumps(summary, indent=2))
        return 0
    from lerobot_taxdpd.sim.cloth.evaluation import evaluate

    summary = evaluate(
        split=args.split,
        seed=args.seed,
        trials=args.trials,
        output=args.output,
        policy_path=args.policy_path,
        goal_policy_path=args.goal_policy_path,
        ground_truth_goals=args.ground_truth_goals,
        num_goal_samples=args.num_goal_samples,
        goal_threshold=args.goal_threshold,
        plots=args.plots,
        workers=args.workers,
        device=args.device,
    )
    print(json.dumps({k: v for k, v in summary.items() if k != "per_trial"}, indent=2))
    print(f"per-trial results: {args.output / 'eval_cloth_hang.json'}")
    if args.ship is not None:
        from lerobot_taxdpd.sim.cloth.evaluation import ship_goal_predictor

        print(f"shipped as {ship_goal_predictor(summary, args.ship)}")
    return 0
