"""What the evaluation harness evaluates: any goal predictor with `sample_goals` or `predict_poses`.

The harness needs only `sample_goals`; a predictor that answers with poses alone (an SE(3) baseline) is
wrapped by `as_goal_predictor`, which moves the object cloud by each pose. The harness turns each sampled
goal cloud into a pose with RANSAC-SVD itself (as the robot would, and as the lerobot-eval env does), so
the pose it executes and the cloud it scores are always the same prediction. A predictor may also offer
`placement_distribution` (TAX-DPD's Dense GMM), which the harness then plots.

`OraclePredictor` is the benchmark's own reference: it answers with the ground truth of the trials it
was built from, optionally off by a rigid error of fixed size. It calibrates the success checks
(ground truth must succeed, tolerance-sized errors must fail) and bounds what a model can reach. With
`orientation="start"` or `"mean"` it keeps the true goal position but turns the object the trivial way
(as it starts, or into the mean goal orientation of those trials): the baselines an orientation-aware
model must beat.
"""

from __future__ import annotations

import hashlib
import importlib
from collections.abc import Iterable
from typing import Protocol, runtime_checkable

import numpy as np
import torch
from torch import Tensor

from lerobot_taxdpd.data.schema import SCENE_KEY
from lerobot_taxdpd.maths.geometry import transform_points
from lerobot_taxdpd.sim.poses import perturbation, transform
from lerobot_taxdpd.sim.tasks import PlacementTask
from lerobot_taxdpd.sim.trials import Trial


def observed_as_trained(task: PlacementTask, predictor: object) -> PlacementTask:
    """`task` observing as many scene points as `predictor` was trained on (its scene input feature): a
    predictor trained on a denser recording crops its local scene from an equally dense one."""
    feature = getattr(getattr(predictor, "config", None), "input_features", {}).get(SCENE_KEY)
    return task.with_scene_cloud_size(feature.shape[0] if feature is not None else None)


@runtime_checkable
class GoalPredictor(Protocol):
    """Anything that samples goal clouds: (B, N_O, 3), (B, N_S, 3), K -> (B, K, N_O, 3), metres."""

    def sample_goals(self, object_points: Tensor, scene_points: Tensor, num_samples: int) -> Tensor: ...


@runtime_checkable
class PosePredictor(Protocol):
    """Anything that samples placement poses: (B, N_O, 3), (B, N_S, 3), K -> (B, K, 4, 4), goal = T @ object."""

    def predict_poses(self, object_points: Tensor, scene_points: Tensor, num_samples: int) -> Tensor: ...


class PoseGoalPredictor:
    """A pose predictor seen as a goal predictor: each sampled pose applied to the object cloud."""

    def __init__(self, predictor: PosePredictor):
        self.predictor = predictor

    def sample_goals(self, object_points: Tensor, scene_points: Tensor, num_samples: int) -> Tensor:
        object_points = torch.as_tensor(object_points, dtype=torch.float32)
        poses = torch.as_tensor(
            self.predictor.predict_poses(object_points, scene_points, num_samples), dtype=torch.float32
        )
        expected = (object_points.shape[0], num_samples, 4, 4)
        if tuple(poses.shape) != expected:
            name = type(self.predictor).__name__
            raise ValueError(f"{name}.predict_poses returned shape {tuple(poses.shape)}, expected {expected}")
        rotations, translations = poses[..., :3, :3], poses[..., :3, 3]
        return torch.einsum("bkij,bnj->bkni", rotations, object_points.to(poses.device)) + translations[:, :, None]


def as_goal_predictor(predictor: object, origin: str = "predictor") -> GoalPredictor:
    """The predictor itself if it samples goal clouds, wrapped if it only predicts poses; else a TypeError."""
    if isinstance(predictor, GoalPredictor):
        return predictor
    if isinstance(predictor, PosePredictor):
        return PoseGoalPredictor(predictor)
    raise TypeError(
        f"{origin}: {type(predictor).__name__} has neither sample_goals(object_points, scene_points, num_samples) "
        "nor predict_poses(object_points, scene_points, num_samples)"
    )


#: How `OraclePredictor` turns the object: as demonstrated, as it starts, or into the trials' mean goal orientation.
ORIENTATIONS = ("goal", "start", "mean")


def _mean_rotation(rotations: list[np.ndarray]) -> np.ndarray:
    """The rotation nearest (chordal distance) to the average of rotation matrices."""
    u, _, vt = np.linalg.svd(np.mean(rotations, axis=0))
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def _cloud_key(points: np.ndarray) -> str:
    return hashlib.sha1(np.ascontiguousarray(points, dtype=np.float32).tobytes()).hexdigest()


def _per_trial(table: dict, object_points: Tensor, owner: str) -> list:
    """`table`'s entry for each object cloud of the batch, the trials being recognised by their object cloud."""
    entries = []
    for cloud in torch.as_tensor(object_points).detach().cpu().numpy():
        entry = table.get(_cloud_key(cloud))
        if entry is None:
            raise ValueError(f"{owner}: object_points do not belong to any trial it was built from")
        entries.append(entry)
    return entries


class OraclePredictor:
    """Ground-truth goals of known trials, with an optional rigid error of exactly the given size.

    Sample 0 is the demonstrator's goal; further samples go through the other valid goals of the scene
    in turn (one per mode), so K >= the number of modes covers them all. With `translation`/`rotation_deg`
    each sample is moved by that distance in a random direction and turned by that angle about a random
    axis through its centroid. Trials are recognised by their object cloud.
    """

    def __init__(
        self,
        trials: Iterable[Trial],
        translation: float = 0.0,
        rotation_deg: float = 0.0,
        seed: int = 0,
        orientation: str = "goal",
    ):
        if translation < 0 or rotation_deg < 0:
            raise ValueError(f"oracle error must be non-negative, got {translation} m and {rotation_deg} deg")
        if orientation not in ORIENTATIONS:
            raise ValueError(f"orientation: must be one of {ORIENTATIONS}, got {orientation!r}")
        self.translation = translation
        self.rotation_deg = rotation_deg
        self._rng = np.random.default_rng(seed)
        self._goals: dict[str, list[np.ndarray]] = {}
        trials = list(trials)
        mean_rotation = _mean_rotation([(t.goal_transform @ t.start_pose)[:3, :3] for t in trials])
        for trial in trials:
            demo = trial.goal_transform
            others = [t[0] for t in trial.valid_transforms() if not any(np.allclose(demo, v) for v in t)]
            if orientation != "goal":  # the demonstrated position, a trivially chosen orientation
                turn = np.eye(3) if orientation == "start" else mean_rotation @ trial.start_pose[:3, :3].T
                centre = trial.object_points.astype(np.float64).mean(0)
                demo, others = transform(turn, transform_points(demo, centre) - turn @ centre), []
            self._goals[_cloud_key(trial.object_points)] = [
                transform_points(t, trial.object_points.astype(np.float64)) for t in (demo, *others)
            ]

    def _perturb(self, goal: np.ndarray) -> np.ndarray:
        if self.translation == 0 and self.rotation_deg == 0:
            return goal
        rotation, shift = perturbation(self._rng, self.translation, self.rotation_deg)
        centre = goal.mean(0)
        return transform_points(transform(rotation, centre + shift - rotation @ centre), goal)

    def sample_goals(self, object_points: Tensor, scene_points: Tensor, num_samples: int) -> Tensor:
        batch = []
        for goals in _per_trial(self._goals, object_points, "OraclePredictor"):
            batch.append(np.stack([self._perturb(goals[k % len(goals)]) for k in range(num_samples)]))
        return torch.from_numpy(np.stack(batch).astype(np.float32))


class TrueFramePredictor:
    """A TAX-DPD predictor sampling at the true placement frame: each sample's frame is the centroid of the
    demonstrated goal of a known trial instead of a Dense GMM sample, so its errors are the local stage's alone.
    Beside the same predictor's own results, it splits the error between where the object goes (the GMM) and
    how it is placed there (the local diffusion)."""

    def __init__(self, predictor, trials: Iterable[Trial]):
        self.predictor = predictor
        self._centroids = {
            _cloud_key(t.object_points): transform_points(t.goal_transform, t.object_points.astype(np.float64)).mean(0)
            for t in trials
        }

    def sample_goals(
        self, object_points: Tensor, scene_points: Tensor, num_samples: int, generator: torch.Generator | None = None
    ) -> Tensor:
        frames = np.stack(_per_trial(self._centroids, object_points, "TrueFramePredictor"))
        return self.predictor.sample_goals(
            object_points, scene_points, num_samples, generator=generator, placement_frames=frames
        )


def load_predictor(spec: str) -> GoalPredictor:
    """`package.module:factory` -> factory(), for baselines outside this package (goal or pose predictors)."""
    module_name, _, attribute = spec.partition(":")
    if not module_name or not attribute:
        raise ValueError(f"--predictor: expected 'oracle' or 'package.module:factory', got {spec!r}")
    factory = getattr(importlib.import_module(module_name), attribute, None)
    if factory is None:
        raise ValueError(f"--predictor: {module_name!r} has no attribute {attribute!r}")
    return as_goal_predictor(factory(), origin=f"--predictor {spec}")
