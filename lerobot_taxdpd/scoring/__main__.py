"""Goal scorers: collect a goal predictor's executed samples on training scenes, train a scorer on them, and use
it to choose which sample to execute (`sim eval --goal-selection scorer`).

    python -m lerobot_taxdpd.scoring collect --task book_shelf --goal-policy.path book_shelf \\
        --seeds 5000 5499 --output data/scorer/book_shelf          # rerun to finish a collection in legs
    python -m lerobot_taxdpd.scoring train --collection data/scorer/book_shelf --output outputs/scorer/book_shelf
    python -m lerobot_taxdpd.sim eval --task book_shelf --goal-policy.path book_shelf \\
        --scorer.path outputs/scorer/book_shelf --seed 1000
    python -m lerobot_taxdpd.scoring ship --scorer outputs/scorer/book_shelf --task book_shelf \\
        --goal-policy.path book_shelf --ship lerobot_taxdpd/pretrained   # seeds 0-99, first vs scorer, paired

cloth_hang collects the same way (each sample hung by the gc_dp3 executor shipped beside the goal predictor, or
`--executor`); `ship` then measures the scorer against the consensus sample (cloth's default) and the first.

The scorer is a plain module with this CLI, not a third LeRobot policy: it acts on nothing (no observation to
action), its examples are (scene, candidate goal, outcome) triples made from a predictor's samples rather than
recorded episodes, and it trains in minutes; it saves, loads and pushes through huggingface_hub like the
policies (`GoalScorer.from_pretrained` takes a folder or a Hub id).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from lerobot_taxdpd.cli_options import add_search_arguments, search_overrides, with_search
from lerobot_taxdpd.threads import add_threads_argument, configure_threads


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m lerobot_taxdpd.scoring", description=__doc__.split("\n\n")[0].replace("\n", " ")
    )
    verbs = parser.add_subparsers(dest="verb", required=True)
    collect = verbs.add_parser("collect", help="execute a goal predictor's samples on training scenes")
    collect.add_argument("--task", required=True, help="a procedural task (e.g. book_shelf) or cloth_hang")
    collect.add_argument("--goal-policy.path", dest="goal_policy_path", required=True, metavar="NAME_OR_PATH")
    collect.add_argument(
        "--seeds",
        type=int,
        nargs=2,
        required=True,
        metavar=("FIRST", "LAST"),
        help="training-geometry scene seeds, inclusive; pick ones past the predictor's demonstrations (0..N-1)",
    )
    collect.add_argument("--output", type=Path, required=True, help="collection folder (shards and collection.json)")
    collect.add_argument("--num-samples", type=int, default=10, help="samples per scene, K (default: 10)")
    collect.add_argument("--shard-size", type=int, default=50, help="scenes per shard file (default: 50)")
    collect.add_argument(
        "--workers",
        type=int,
        default=1,
        help="processes labelling shards side by side, one torch thread each (default: 1); one per core",
    )
    collect.add_argument(
        "--executor",
        metavar="NAME_OR_PATH",
        help="cloth_hang only: the gc_dp3 policy that hangs each sampled goal (default: the goal predictor's name)",
    )
    collect.add_argument(
        "--shifted-copies",
        type=int,
        default=0,
        metavar="N",
        help="rigid tasks: also execute N copies a scene of its samples moved in x and y, so that a scorer that "
        "searches (--search-extent-mm) learns what a shift does (default: 0)",
    )
    collect.add_argument(
        "--shift-extent-mm", type=float, default=0.0, metavar="MM", help="how far those copies move at most"
    )
    add_threads_argument(collect)
    train = verbs.add_parser("train", help="train a scorer on a collection")
    train.add_argument("--collection", type=Path, required=True)
    train.add_argument("--output", type=Path, required=True, help="folder for the scorer (config, weights, metrics)")
    train.add_argument("--steps", type=int, default=2000)
    train.add_argument("--batch-scenes", type=int, default=8, help="scenes a step, each with all its K samples")
    train.add_argument("--seed", type=int, default=0)
    train.add_argument(
        "--num-goal-points",
        type=int,
        default=None,
        help="candidate points the scorer looks at, the first of each cloud (default: GoalScorerConfig's)",
    )
    train.add_argument(
        "--start-displacement",
        action="store_true",
        help="also show the scorer each candidate point's offset from the start object (for cloth: how far the "
        "executor must carry each part)",
    )
    add_search_arguments(train)
    add_threads_argument(train)
    ship = verbs.add_parser("ship", help="measure a scorer against the first sample, paired, and ship it")
    ship.add_argument("--scorer", type=Path, required=True, help="a folder written by `train`")
    ship.add_argument("--task", required=True)
    ship.add_argument("--goal-policy.path", dest="goal_policy_path", required=True, metavar="NAME_OR_PATH")
    ship.add_argument("--trials", type=int, default=100, help="held-out trials, seeds 0..N-1 (default: 100)")
    ship.add_argument("--num-samples", type=int, default=10)
    ship.add_argument("--ship", type=Path, default=None, help="save it as <SHIP>/<task>/scorer (default: measure only)")
    ship.add_argument(
        "--workers",
        type=int,
        default=1,
        help="cloth_hang only: parallel simulation processes (default: 1); its per-trial report is written in "
        "<SCORER>/evaluation",
    )
    add_search_arguments(ship)
    add_threads_argument(ship)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_threads(args.threads)
    try:
        if args.verb == "collect":
            from lerobot_taxdpd.scoring.collect import collect

            first, last = args.seeds
            if last < first:
                raise ValueError(f"--seeds: LAST ({last}) is before FIRST ({first})")
            shards = collect(
                args.task,
                args.goal_policy_path,
                range(first, last + 1),
                args.output,
                num_samples=args.num_samples,
                shard_size=args.shard_size,
                executor=args.executor,
                workers=args.workers,
                shifted_copies=args.shifted_copies,
                shift_extent_mm=args.shift_extent_mm,
            )
            print(f"{len(shards)} shards in {args.output}")
        elif args.verb == "ship":
            from lerobot_taxdpd.scoring.shipping import evaluate_choice, ship_scorer

            search = search_overrides(args)
            evaluation = evaluate_choice(
                args.task,
                args.goal_policy_path,
                str(args.scorer),
                range(args.trials),
                args.num_samples,
                workers=args.workers,
                search=search,
            )
            print(json.dumps(evaluation, indent=2))
            if args.ship is not None:
                shipped = ship_scorer(args.scorer, args.goal_policy_path, evaluation, args.ship, search=search)
                print(f"shipped as {shipped}")
        else:
            from lerobot_taxdpd.policies.goal_scorer import GoalScorerConfig
            from lerobot_taxdpd.scoring.training import train_scorer

            config = GoalScorerConfig(
                **({"num_goal_points": args.num_goal_points} if args.num_goal_points else {}),
                start_displacement=args.start_displacement,
            )
            metrics = train_scorer(
                args.collection,
                args.output,
                steps=args.steps,
                batch_scenes=args.batch_scenes,
                seed=args.seed,
                config=with_search(config, args),
            )
            print(json.dumps(metrics["held_back_scenes"]))
            print(f"scorer saved in {args.output}")
    except (ValueError, FileNotFoundError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
