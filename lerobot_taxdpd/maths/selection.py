"""Which of the K sampled goals a robot executes.

The paper executes one sample. When most samples are right, the right ones agree with each other (they sit
on the same few valid goals) while the wrong ones scatter, so the sample with the most neighbours is more
often a valid goal than a sample taken blindly: a vote among the K. A learned scorer (`lerobot_taxdpd.scoring`,
trained on executed samples, as RPDiff trains a success classifier) picks the sample it scores highest.
"""

from __future__ import annotations

import numpy as np

from lerobot_taxdpd.maths.metrics import pairwise_rmse

#: `first`: the first sample (the paper's one shot); `consensus`: the sample most others agree with; `scorer`:
#: the sample a learned scorer rates highest.
GOAL_SELECTIONS = ("first", "consensus", "scorer")


def agreement(samples: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """For K samples (K, N, 3): how many other samples lie within `radius` RMSE of each (K,), and the pairwise
    RMSEs (K, K). Point clouds are compared row by row: the samples of one predictor share the object's
    point order."""
    samples = np.asarray(samples, dtype=np.float64)
    if samples.ndim != 3 or samples.shape[0] < 1:
        raise ValueError(f"samples: expected (K, N, 3) with K >= 1, got shape {samples.shape}")
    if radius <= 0:
        raise ValueError(f"radius: must be positive, got {radius}")
    rmse = pairwise_rmse(samples, samples)
    return (rmse < radius).sum(1) - 1, rmse


def consensus_index(samples: np.ndarray, radius: float) -> int:
    """Index of the sample with the most other samples within `radius` RMSE of it; ties go to the one with
    the smallest mean RMSE to the others, then to the earliest."""
    neighbours, rmse = agreement(samples, radius)
    total_rmse = rmse.sum(1)  # orders the samples as their mean RMSE to the others does
    return int(np.lexsort((np.arange(len(samples)), total_rmse, -neighbours))[0])


def check_goal_selection(selection: str) -> str:
    """`selection` if it names a rule; a clear error before any trial runs otherwise."""
    if selection not in GOAL_SELECTIONS:
        raise ValueError(f"goal selection: expected one of {', '.join(GOAL_SELECTIONS)}, got {selection!r}")
    return selection


def executed_first(
    samples: np.ndarray, selection: str, radius: float, scores: np.ndarray | None = None
) -> tuple[np.ndarray, int]:
    """The samples reordered so that the one to execute comes first (the others keep their order), and the
    index it had. Callers then execute row 0 whatever the rule; `scorer` needs the K `scores`."""
    if check_goal_selection(selection) == "first":
        return samples, 0
    if selection == "scorer":
        if scores is None or len(scores) != len(samples):
            raise ValueError("goal selection 'scorer': needs one score per sample (give a scorer)")
        index = int(np.argmax(scores))
    else:
        index = consensus_index(samples, radius)
    order = [index, *(i for i in range(len(samples)) if i != index)]
    return samples[order], index
