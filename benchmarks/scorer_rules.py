"""Selection rules scored on a scorer collection, out of fold: every scene's samples are scored by a scorer that
did not train on that scene, and each rule's choice is looked up in the scene's executed outcomes.

A collection labels all K samples of a scene, so any rule can be scored on every collected scene without
executing anything again: the first sample, the consensus one, the learned scorer's choice, the consensus
with ties broken by the scorer, and the best of the K (an oracle). With `--folds F` the scenes are split into
F contiguous folds; F scorers each train on the other folds. `--train-fraction` trains each on a share of them,
which shows whether more collected scenes would still help. Figures with machine and settings in the JSON.

    python benchmarks/scorer_rules.py --collection data/scorer/cloth_hang --folds 5
    python benchmarks/scorer_rules.py --collection data/scorer/cloth_hang --folds 5 --train-fraction 0.5
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from lerobot_taxdpd.data.schema import CLOTH_TASK
from lerobot_taxdpd.maths.metrics import success_summary
from lerobot_taxdpd.maths.selection import agreement, consensus_index
from lerobot_taxdpd.reports.benchmarking import machine_info, write_json
from lerobot_taxdpd.scoring.collect import load_collection
from lerobot_taxdpd.scoring.training import choice_rates, fit_scorer, score_scenes
from lerobot_taxdpd.threads import add_threads_argument, configure_threads

#: The consensus radius of cloth_hang: its coverage threshold (RMSE, in the units of its clouds).
CLOTH_RADIUS = 0.5


def out_of_fold_scores(data: dict, folds: int, train_fraction: float, steps: int, seed: int) -> np.ndarray:
    """(scenes, K) logits, each scene's from the scorer of the fold that held it out."""
    scenes = len(data["seed"])
    rng = np.random.default_rng(seed)
    scores = np.zeros(data["success"].shape, dtype=np.float64)
    for held in np.array_split(np.arange(scenes), folds):
        rest = np.setdiff1d(np.arange(scenes), held)
        rows = np.sort(rng.choice(rest, size=max(1, round(len(rest) * train_fraction)), replace=False))
        scorer, _ = fit_scorer(data, rows, steps=steps, seed=seed)
        scores[held] = score_scenes(scorer, data, held)
    return scores


def rule_choices(samples: np.ndarray, scores: np.ndarray, radius: float) -> dict[str, np.ndarray]:
    """The index each rule executes, per scene."""
    choices = {"first": [], "consensus": [], "scorer": [], "consensus, ties by the scorer": []}
    for scene_samples, scene_scores in zip(samples, scores, strict=True):
        neighbours, _ = agreement(scene_samples, radius)
        most = np.flatnonzero(neighbours == neighbours.max())
        choices["first"].append(0)
        choices["consensus"].append(consensus_index(scene_samples, radius))
        choices["scorer"].append(int(np.argmax(scene_scores)))
        choices["consensus, ties by the scorer"].append(int(most[np.argmax(scene_scores[most])]))
    return {rule: np.asarray(index) for rule, index in choices.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--collection", type=Path, required=True)
    parser.add_argument("--folds", type=int, default=5)
    parser.add_argument("--train-fraction", type=float, default=1.0, help="share of the other folds trained on")
    parser.add_argument("--steps", type=int, default=2000, help="training steps of each fold's scorer")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--radius", type=float, default=None, help="consensus radius (default: the task's)")
    parser.add_argument("--output", type=Path, default=Path("results/scorer_rules.json"))
    add_threads_argument(parser)
    args = parser.parse_args(argv)
    configure_threads(args.threads)
    details, data = load_collection(args.collection)
    if args.radius is None and details["task"] != CLOTH_TASK:
        from lerobot_taxdpd.sim.tasks import get_task

        args.radius = get_task(details["task"]).coverage_threshold
    radius = args.radius if args.radius is not None else CLOTH_RADIUS
    started = time.perf_counter()
    scores = out_of_fold_scores(data, args.folds, args.train_fraction, args.steps, args.seed)
    success = data["success"].astype(bool)
    rows = np.arange(len(success))
    rules = {
        rule: success_summary(int(success[rows, index].sum()), len(rows))
        for rule, index in rule_choices(data["samples"], scores, radius).items()
    }
    rules["best of the K (oracle)"] = success_summary(int(success.any(1).sum()), len(rows))
    report = {
        "machine": machine_info(),
        "collection": details,
        "scenes": len(rows),
        "settings": vars(args) | {"collection": str(args.collection), "output": str(args.output), "radius": radius},
        "rules": rules,
        "pairs_ordered": choice_rates(scores, success)["pairs_ordered"],
        "seconds": time.perf_counter() - started,
    }
    write_json(args.output, report)
    print(f"{details['task']}: {len(rows)} scenes, {args.folds} folds, train fraction {args.train_fraction}")
    for rule, rate in rules.items():
        print(f"  {rule:<32} {rate['success_rate']:.1%} ({rate['ci95_low']:.0%}-{rate['ci95_high']:.0%})")
    print(f"  scorer orders {report['pairs_ordered']:.1%} of a scene's (success, failure) pairs right")
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
