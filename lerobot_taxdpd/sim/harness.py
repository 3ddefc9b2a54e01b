"""The evaluation harness: run a goal predictor on held-out trials and report it under DESIGN's names.

For every trial the predictor samples K goal clouds; one is executed after RANSAC-SVD turns it into a pose:
the first (one shot, no reranking, as in the paper), with `goal_selection="consensus"` the sample the
others agree with most (`maths.selection`), or with `"scorer"` the one a learned scorer rates highest (moved
where the scorer rates it highest, when the scorer searches around its samples).
Errors are measured against the valid goal nearest to the executed sample (the demonstrated goal when the
task has one mode and the object no symmetry), so a sample that solves the scene another valid way is not
penalised. Multi-modal tasks also get coverage@K and precision@K, counting each mode (peg, slot, support,
socket) once.

Every random draw of a trial comes from its scene seed: the predictor gets a `torch.Generator` seeded with
it (when its `sample_goals` takes `generator=`; torch's global generator is seeded with it otherwise) and
RANSAC another, so the same command gives the same numbers on every run, whatever ran before the trial.
"""

from __future__ import annotations

import inspect
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from lerobot_taxdpd.goal_predictors import has_placement_distribution
from lerobot_taxdpd.maths.geometry import estimate_rigid_transform, transform_points
from lerobot_taxdpd.maths.metrics import (
    coverage_precision_from_rmse,
    score_against_valid_goals,
    success_summary,
    transform_errors,
)
from lerobot_taxdpd.maths.selection import check_goal_selection, executed_first
from lerobot_taxdpd.reports.benchmarking import machine_info
from lerobot_taxdpd.reports.plots import plot_goal_samples, plot_weight_map
from lerobot_taxdpd.sim.predictors import GoalPredictor, as_goal_predictor
from lerobot_taxdpd.sim.trials import Outcome, Trial, execute


def _takes_generator(predictor: GoalPredictor) -> bool:
    parameters = inspect.signature(predictor.sample_goals).parameters.values()
    return any(p.name == "generator" or p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters)


def sample_trial_goals(predictor: GoalPredictor, trial: Trial, num_samples: int) -> np.ndarray:
    """The predictor's K goal clouds for one trial as float64 (K, N_O, 3), checked; drawn from the trial's seed."""
    object_points = torch.from_numpy(trial.object_points)[None]
    scene_points = torch.from_numpy(trial.scene_points)[None]
    seeded = {"generator": torch.Generator().manual_seed(trial.seed)} if _takes_generator(predictor) else {}
    with torch.inference_mode(), torch.random.fork_rng():
        torch.manual_seed(trial.seed)  # for predictors that draw from torch's global generator
        samples = predictor.sample_goals(object_points, scene_points, num_samples, **seeded)
    samples = np.asarray(samples.detach().cpu() if isinstance(samples, torch.Tensor) else samples, dtype=np.float64)
    expected = (1, num_samples, *trial.object_points.shape)
    if samples.shape != expected:
        raise ValueError(f"{type(predictor).__name__}.sample_goals returned shape {samples.shape}, expected {expected}")
    if not np.isfinite(samples).all():
        raise ValueError(f"{type(predictor).__name__}.sample_goals returned NaN or infinite coordinates")
    return samples[0]


def _summary(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    array = np.asarray(values)
    return {"median": float(np.median(array)), "mean": float(array.mean()), "p90": float(np.percentile(array, 90))}


def score_trial(trial: Trial, samples: np.ndarray, transform: np.ndarray) -> dict:
    """Errors of the executed sample (row 0 of `samples`, posed by `transform`) and of all K samples."""
    object_points = trial.object_points.astype(np.float64)
    valid = trial.valid_transforms()
    goals = [transform_points(t, object_points) for t in valid]  # per mode: (V, N, 3)
    flat_goals = np.concatenate(goals)
    flat_transforms = np.concatenate(valid)
    scores = score_against_valid_goals(samples, flat_goals)  # against every variant of every mode
    rmse, nearest = scores.rmse, int(scores.nearest[0])
    record = {
        "translation_error_mm": float(scores.translation_error[0]) * 1000,
        "rotation_error_deg": float(scores.rotation_error_deg[0]),
        "rmse_mm": float(scores.nearest_rmse[0]) * 1000,
        "winner_take_all_rmse_mm": float(rmse.min()) * 1000,
        "nearest_goal_mode": trial.modes[
            int(np.searchsorted(np.cumsum([len(g) for g in goals]), nearest, side="right"))
        ].label,
    }
    # The pose that ran (RANSAC-SVD's fit) can be further off than the cloud's centroid and Procrustes turn above,
    # the paper's metrics, when the sampled cloud is distorted.
    translation, rotation = transform_errors(transform @ trial.start_pose, flat_transforms[nearest] @ trial.start_pose)
    record["executed_pose_translation_error_mm"] = float(translation) * 1000
    record["executed_pose_rotation_error_deg"] = float(rotation)
    if trial.gripper_pose is not None:
        translation, rotation = transform_errors(
            transform @ trial.gripper_pose, flat_transforms[nearest] @ trial.gripper_pose
        )
        record["gripper_translation_error_mm"] = float(translation) * 1000
        record["gripper_rotation_error_deg"] = float(rotation)
    if trial.task.multi_modal:
        bounds = np.cumsum([0, *[len(g) for g in goals]])
        spans = zip(bounds[:-1], bounds[1:], strict=True)
        per_mode = np.stack([rmse[:, a:b].min(1) for a, b in spans], 1)  # (K, modes)
        quality = coverage_precision_from_rmse(per_mode, trial.task.coverage_threshold)
        record.update(coverage=quality["coverage"], precision=quality["precision"], num_modes=len(goals))
    return record


@dataclass(frozen=True)
class TrialRun:
    """One trial as the harness runs it: the K samples (the executed one first), what executing it did, and the
    trial's record of the report."""

    samples: np.ndarray  # (K, N_O, 3) float64, metres
    outcome: Outcome
    record: dict
    predict_seconds: float


def execute_sample(trial: Trial, sample: np.ndarray) -> tuple[np.ndarray, Outcome]:
    """Fit a pose to one sampled goal cloud by RANSAC-SVD (seeded by the trial) and execute it: the pose and
    what executing it did."""
    transform, _ = estimate_rigid_transform(
        trial.object_points.astype(np.float64), sample, generator=torch.Generator().manual_seed(trial.seed)
    )
    return transform, execute(trial, transform)


def run_trial(
    predictor: GoalPredictor, trial: Trial, num_samples: int, goal_selection: str = "first", scorer=None
) -> TrialRun:
    """Sample K goals (from the trial's seed), pick one by `goal_selection` (`scorer`: a `GoalScorer`), fit a
    pose to it by RANSAC-SVD, execute and score it."""
    tick = time.perf_counter()
    samples = sample_trial_goals(predictor, trial, num_samples)
    choice = None
    if goal_selection == "scorer":
        scene, start = torch.from_numpy(trial.scene_points), torch.from_numpy(trial.object_points)
        choice = scorer.choose(torch.from_numpy(samples), scene, start)
    predict_seconds = time.perf_counter() - tick
    scores = None if choice is None else choice.scores.numpy()
    samples, executed = executed_first(samples, goal_selection, trial.task.coverage_threshold, scores)
    if choice is not None:
        samples[0] = choice.goal.numpy()  # the chosen sample as the scorer's search moved it
    transform, outcome = execute_sample(trial, samples[0])
    record = {
        "seed": trial.seed,
        "success": outcome.success,
        "failure": outcome.reason,
        "reached_goal": outcome.reached_goal,
        "executed_sample": executed,
        **score_trial(trial, samples, transform),
    }
    if choice is not None:
        record["executed_shift_mm"] = [round(float(x) * 1000, 3) for x in choice.shift]
    return TrialRun(samples, outcome, record, predict_seconds)


def evaluate(
    predictor: GoalPredictor,
    trials: Iterable[Trial],
    num_samples: int,
    *,
    goal_selection: str = "first",
    scorer=None,
    figures_dir: Path | None = None,
    num_figures: int = 3,
    progress: bool = True,
    total: int | None = None,
) -> dict:
    """Run every trial and return the report (see module docstring); PNGs go to `figures_dir`."""
    if num_samples < 1:
        raise ValueError(f"num_samples: must be at least 1, got {num_samples}")
    check_goal_selection(goal_selection)
    if (goal_selection == "scorer") != (scorer is not None):
        raise ValueError("goal selection 'scorer' and a scorer go together: give both or neither")
    predictor = as_goal_predictor(predictor)
    if figures_dir is not None:
        figures_dir = Path(figures_dir)
        figures_dir.mkdir(parents=True, exist_ok=True)
    records, figures, task = [], [], None
    started = time.perf_counter()
    for index, trial in enumerate(tqdm(trials, total=total, desc="trials", disable=not progress)):
        task = trial.task
        tick = time.perf_counter()
        run = run_trial(predictor, trial, num_samples, goal_selection, scorer)
        record = {**run.record, "predict_seconds": run.predict_seconds, "seconds": time.perf_counter() - tick}
        records.append(record)
        if figures_dir is not None and index < num_figures:
            figures += _draw(predictor, trial, run.samples, run.outcome.success, figures_dir)
    if not records:
        raise ValueError("no trials to evaluate")
    report = _report(task, trial.split, records, num_samples, figures, time.perf_counter() - started)
    return {**report, "goal_selection": goal_selection}


def _draw(predictor: GoalPredictor, trial: Trial, samples: np.ndarray, success: bool, folder: Path) -> list[str]:
    """PNGs of one trial: its K samples, and the Dense GMM's weights where the predictor has one."""
    stem = folder / f"{trial.task.name}_seed{trial.seed}"
    title = f"{trial.task.name}, seed {trial.seed}"
    verdict = " - executed sample succeeded" if success else " - executed sample failed"
    paths = [
        plot_goal_samples(
            f"{stem}_samples.png",
            trial.scene_points,
            trial.object_points,
            samples,
            valid_goals=[trial.goal_points()],
            goals_label="ground-truth goal",
            title=f"{title}: {len(samples)} sampled goals{verdict}",
        )
    ]
    if has_placement_distribution(predictor):
        with torch.inference_mode():
            weights, means = predictor.placement_distribution(
                torch.from_numpy(trial.object_points)[None], torch.from_numpy(trial.scene_points)[None]
            )
        paths.append(
            plot_weight_map(
                f"{stem}_gmm.png",
                trial.scene_points,
                np.asarray(weights[0].cpu()),
                np.asarray(means[0].cpu()),
                goal_centroids=trial.goal_points().mean(0),
                centroids_label="ground-truth goal centroid",
                title=f"{title}: Dense GMM over the scene",
            )
        )
    return [str(path) for path in paths]


def _report(task, split: str, records: list[dict], num_samples: int, figures: list[str], seconds: float) -> dict:
    successes = sum(r["success"] for r in records)
    report = {
        "task": task.name,
        "split": split,
        "trials": len(records),
        "num_samples": num_samples,
        "success": success_summary(successes, len(records)),
        "errors_against": "the valid goal nearest to the executed sample",
        "translation_error_mm": _summary([r["translation_error_mm"] for r in records]),
        "rotation_error_deg": _summary([r["rotation_error_deg"] for r in records]),
        "executed_pose_translation_error_mm": _summary([r["executed_pose_translation_error_mm"] for r in records]),
        "executed_pose_rotation_error_deg": _summary([r["executed_pose_rotation_error_deg"] for r in records]),
        "rmse_mm": _summary([r["rmse_mm"] for r in records]),
        "winner_take_all_rmse_mm": _summary([r["winner_take_all_rmse_mm"] for r in records]),
        "failures": dict(Counter(r["failure"].split(" (")[0] for r in records if not r["success"])),
        "seconds_per_trial": _summary([r["seconds"] for r in records]),
        "predict_seconds_per_trial": _summary([r["predict_seconds"] for r in records]),
        "wall_seconds": seconds,
        "machine": machine_info(),
        "figures": figures,
        "per_trial": records,
    }
    if "gripper_translation_error_mm" in records[0]:
        report["gripper_translation_error_mm"] = _summary([r["gripper_translation_error_mm"] for r in records])
        report["gripper_rotation_error_deg"] = _summary([r["gripper_rotation_error_deg"] for r in records])
    if "coverage" in records[0]:
        report[f"coverage@{num_samples}"] = float(np.mean([r["coverage"] for r in records]))
        report[f"precision@{num_samples}"] = float(np.mean([r["precision"] for r in records]))
        report["coverage_threshold_mm"] = task.coverage_threshold * 1000
    return report
