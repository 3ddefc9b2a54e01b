"""The metrics every report uses, under the names of DESIGN.md.

Clouds are (..., N, 3) numpy arrays or tensors in metres; errors come back as numpy in the units named by
each function (metres unless `_mm`/`_deg`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from lerobot_taxdpd.maths.geometry import fit_rigid_transform, rotation_angle


def _np(x) -> np.ndarray:
    return x.detach().cpu().double().numpy() if isinstance(x, torch.Tensor) else np.asarray(x, dtype=np.float64)


def point_rmse(prediction, target) -> np.ndarray:
    """Per-point RMSE between corresponding clouds: sqrt(mean_i |p_i - q_i|^2), over the last two axes."""
    diff = _np(prediction) - _np(target)
    return np.sqrt((diff**2).sum(-1).mean(-1))


def winner_take_all_rmse(samples, target) -> np.ndarray:
    """min over K of the per-point RMSE: samples (B, K, N, 3), target (B, N, 3) -> (B,)."""
    return point_rmse(samples, _np(target)[:, None]).min(-1)


def translation_error(prediction, target) -> np.ndarray:
    """Distance between the centroids of predicted and true goal clouds (metres)."""
    return np.linalg.norm(_np(prediction).mean(-2) - _np(target).mean(-2), axis=-1)


def rotation_error_deg(prediction, target) -> np.ndarray:
    """Angle (degrees) of the Procrustes rotation that best aligns the predicted cloud to the true one."""
    transform = fit_rigid_transform(_np(prediction), _np(target))
    return np.degrees(rotation_angle(torch.from_numpy(transform[..., :3, :3])).numpy())


def transform_errors(predicted_transform, true_transform) -> tuple[np.ndarray, np.ndarray]:
    """Translation (metres) and rotation (degrees) differences between (..., 4, 4) poses."""
    p, t = _np(predicted_transform), _np(true_transform)
    translation = np.linalg.norm(p[..., :3, 3] - t[..., :3, 3], axis=-1)
    relative = np.swapaxes(p[..., :3, :3], -1, -2) @ t[..., :3, :3]
    return translation, np.degrees(rotation_angle(torch.from_numpy(relative)).numpy())


def pairwise_rmse(predictions, goals) -> np.ndarray:
    """RMSE matrix between K predictions (K, N, 3) and M valid goals (M, N, 3) -> (K, M)."""
    return point_rmse(_np(predictions)[:, None], _np(goals)[None])


@dataclass(frozen=True)
class NearestGoalScores:
    """K sampled goals, each scored against the valid goal nearest to it (metres and degrees)."""

    rmse: np.ndarray  # (K, M): every sample against every valid goal
    nearest: np.ndarray  # (K,): index of each sample's nearest valid goal
    nearest_rmse: np.ndarray  # (K,)
    translation_error: np.ndarray  # (K,) to that goal
    rotation_error_deg: np.ndarray  # (K,) to that goal


def score_against_valid_goals(samples, valid_goals) -> NearestGoalScores:
    """Score K samples (K, N, 3) against M valid goals (M, N, 3) of one scene.

    A sample that solves the scene another valid way is not penalised: its errors are measured against the
    valid goal nearest to it (by per-point RMSE), not against the one a demonstrator happened to choose.
    """
    samples, valid_goals = _np(samples), _np(valid_goals)
    rmse = pairwise_rmse(samples, valid_goals)
    nearest = rmse.argmin(1)
    targets = valid_goals[nearest]
    return NearestGoalScores(
        rmse=rmse,
        nearest=nearest,
        nearest_rmse=rmse.min(1),
        translation_error=translation_error(samples, targets),
        rotation_error_deg=rotation_error_deg(samples, targets),
    )


def coverage_precision(predictions, goals, threshold: float) -> dict[str, float]:
    """Multi-modal quality of K samples against the M valid goals of one scene.

    coverage: fraction of valid goals within `threshold` RMSE of at least one sample;
    precision: fraction of samples within `threshold` of some valid goal;
    coverage_rmse / precision_rmse: mean over goals (samples) of the best RMSE to any sample (goal).
    """
    return coverage_precision_from_rmse(pairwise_rmse(predictions, goals), threshold)


def coverage_precision_from_rmse(rmse, threshold: float) -> dict[str, float]:
    """`coverage_precision` from a (K samples, M goals) RMSE matrix.

    Lets callers fold equivalent goals first, e.g. take the min over the symmetric poses of one slot so
    that a slot counts once however its object is turned.
    """
    rmse = _np(rmse)
    best_per_goal = rmse.min(0)
    best_per_sample = rmse.min(1)
    return {
        "coverage": float((best_per_goal < threshold).mean()),
        "precision": float((best_per_sample < threshold).mean()),
        "coverage_rmse": float(best_per_goal.mean()),
        "precision_rmse": float(best_per_sample.mean()),
    }


def wilson_interval(successes: int, trials: int, z: float = 1.96) -> tuple[float, float]:
    """95% Wilson score interval of a success rate (well-behaved at 0% and 100%, unlike the normal one)."""
    if trials <= 0:
        return (0.0, 1.0)
    p = successes / trials
    denom = 1 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denom
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


def success_summary(successes: int, trials: int) -> dict[str, float]:
    low, high = wilson_interval(successes, trials)
    return {"success_rate": successes / max(trials, 1), "ci95_low": low, "ci95_high": high, "trials": trials}


def paired_outcomes(a, b, names: tuple[str, str] = ("a", "b")) -> dict[str, int]:
    """Counts of the same trials run two ways (success lists `a` and `b`): both, only the one named
    `names[0]`, only the other, neither. The two middle counts are what a difference between the rules rests on."""
    a, b = _np(a).astype(bool), _np(b).astype(bool)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"paired_outcomes: needs two 1-D outcome lists of one length, got {a.shape} and {b.shape}")
    return {
        "both": int((a & b).sum()),
        f"only_{names[0]}": int((a & ~b).sum()),
        f"only_{names[1]}": int((~a & b).sum()),
        "neither": int((~a & ~b).sum()),
    }


def paired_difference(a, b, resamples: int = 10_000, seed: int = 0) -> tuple[float, float, float]:
    """Mean of `a - b` over paired trials (the same scenes scored twice) with a 95% bootstrap interval.

    Pairing removes the scene-to-scene spread, so two variants evaluated on the same seeds can be told
    apart even where their own intervals overlap."""
    a, b = _np(a).astype(np.float64), _np(b).astype(np.float64)
    if a.shape != b.shape or a.ndim != 1 or a.size == 0:
        raise ValueError(
            f"paired_difference: needs two 1-D arrays of the same non-zero length, got {a.shape} and {b.shape}"
        )
    difference = a - b
    rng = np.random.default_rng(seed)
    means = difference[rng.integers(0, difference.size, (resamples, difference.size))].mean(1)
    low, high = np.percentile(means, [2.5, 97.5])
    return float(difference.mean()), float(low), float(high)
