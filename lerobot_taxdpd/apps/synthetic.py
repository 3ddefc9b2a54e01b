"""A small synthetic placement task with two valid goals: a keyed box into one of two keyed slots.

The object is a 6 x 3 x 3 cm box with a 2 cm handle block on its +x end; each slot is a low fence around a
7 x 4 cm footprint with a post at the end where the handle must go. Every scene has two slots at random
positions and yaws, so the goal distribution has exactly two modes, each with a precise pose. It needs no
simulator and makes the built-in demo and the learning tests self-contained.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lerobot_taxdpd.data.dataset_writer import DatasetCardInfo, DatasetWriter
from lerobot_taxdpd.data.schema import GOAL_DATASET_FPS, goal_prediction_features, placement_frame
from lerobot_taxdpd.goal_predictors import has_placement_distribution

TASK = "put the keyed box into one of the two keyed slots, handle towards the post"

BOX = np.array([0.06, 0.03, 0.03])
HANDLE = np.array([0.02, 0.02, 0.02])
SLOT = np.array([0.07, 0.04])
FENCE_HEIGHT = 0.015
POST_HEIGHT = 0.04
TABLE_HALF = 0.25


@dataclass
class SlotScene:
    object_points: np.ndarray  # (N_O, 3)
    scene_points: np.ndarray  # (N_S, 3)
    goal_points: np.ndarray  # (N_O, 3): the goal in the slot the demonstrator chose
    goal_transform: np.ndarray  # (4, 4)
    valid_goals: np.ndarray  # (2, N_O, 3): one goal per slot
    slot_centres: np.ndarray  # (2, 3)


def _pose(yaw: float, position) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    transform = np.eye(4)
    transform[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    transform[:3, 3] = position
    return transform


def _apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ transform[:3, :3].T + transform[:3, 3]


def _box_surface(rng: np.random.Generator, size: np.ndarray, centre: np.ndarray, n: int) -> np.ndarray:
    """n points uniform on the surface of an axis-aligned box."""
    areas = np.array([size[1] * size[2], size[0] * size[2], size[0] * size[1]]).repeat(2)
    face = rng.choice(6, size=n, p=areas / areas.sum())
    points = rng.uniform(-0.5, 0.5, size=(n, 3)) * size
    axis = face // 2
    points[np.arange(n), axis] = np.where(face % 2 == 0, -0.5, 0.5) * size[axis]
    return points + centre


def keyed_box(rng: np.random.Generator, n: int) -> np.ndarray:
    """Object points in its own frame (bottom face at z = 0, box centred on x/y, handle at +x)."""
    n_handle = n // 6
    body = _box_surface(rng, BOX, np.array([0.0, 0.0, BOX[2] / 2]), n - n_handle)
    handle = _box_surface(rng, HANDLE, np.array([BOX[0] / 2 + HANDLE[0] / 2, 0.0, HANDLE[2] / 2]), n_handle)
    return np.concatenate([body, handle])


def _keyed_slot(rng: np.random.Generator, n: int) -> np.ndarray:
    """A fence around the slot footprint plus the post at +x, in the slot's frame."""
    n_post = n // 5
    length, width = SLOT
    walls = []
    per_wall = (n - n_post) // 4
    for axis, half_extent, span in ((0, length / 2, width), (1, width / 2, length)):
        for sign in (-1.0, 1.0):
            wall = np.zeros((per_wall, 3))
            wall[:, axis] = sign * half_extent
            wall[:, 1 - axis] = rng.uniform(-span / 2, span / 2, per_wall)
            wall[:, 2] = rng.uniform(0.0, FENCE_HEIGHT, per_wall)
            walls.append(wall)
    post_size, post_centre = np.array([0.01, 0.01, POST_HEIGHT]), np.array([length / 2 + 0.01, 0.0, POST_HEIGHT / 2])
    post = _box_surface(rng, post_size, post_centre, n_post)
    fence = np.concatenate(walls)
    fill = n - n_post - len(fence)
    return np.concatenate([fence, post, fence[rng.choice(len(fence), fill)]])


@dataclass
class SlotLayout:
    """What stays fixed across the views of one demo: slot poses, the object's start pose, the chosen slot."""

    slot_poses: list[np.ndarray]
    start_pose: np.ndarray
    chosen: int


def sample_slot_layout(rng: np.random.Generator, yaw_range: float = math.pi) -> SlotLayout:
    """Two slots at least 15 cm apart; slot yaws and the object's start yaw in [-yaw_range, yaw_range]."""
    while True:
        centres = rng.uniform(-TABLE_HALF + 0.06, TABLE_HALF - 0.06, size=(2, 2))
        if np.linalg.norm(centres[0] - centres[1]) > 0.15:
            break
    slot_poses = [_pose(rng.uniform(-yaw_range, yaw_range), [*c, 0.0]) for c in centres]
    start = _pose(rng.uniform(-yaw_range, yaw_range), [*rng.uniform(-0.1, 0.1, 2), 0.15])
    return SlotLayout(slot_poses, start, int(rng.integers(2)))


def render_slot_scene(
    layout: SlotLayout, rng: np.random.Generator, num_object_points: int = 128, num_scene_points: int = 256
) -> SlotScene:
    """Point clouds of a layout; `rng` only draws the surface samples."""
    n_table = num_scene_points // 4
    table = np.column_stack([rng.uniform(-TABLE_HALF, TABLE_HALF, (n_table, 2)), np.zeros(n_table)])
    per_slot = (num_scene_points - n_table) // 2
    slots = [_apply(pose, _keyed_slot(rng, per_slot)) for pose in layout.slot_poses]
    scene = np.concatenate([table, *slots, slots[0][: num_scene_points - n_table - 2 * per_slot]])
    canonical = keyed_box(rng, num_object_points)
    valid = np.stack([_apply(pose, canonical) for pose in layout.slot_poses])
    return SlotScene(
        object_points=_apply(layout.start_pose, canonical).astype(np.float32),
        scene_points=scene.astype(np.float32),
        goal_points=valid[layout.chosen].astype(np.float32),
        goal_transform=layout.slot_poses[layout.chosen] @ np.linalg.inv(layout.start_pose),
        valid_goals=valid.astype(np.float32),
        slot_centres=np.stack([pose[:3, 3] for pose in layout.slot_poses]),
    )


def make_slot_scene(
    rng: np.random.Generator, num_object_points: int = 128, num_scene_points: int = 256, yaw_range: float = math.pi
) -> SlotScene:
    """One random scene (layout and sampling from the same generator)."""
    return render_slot_scene(sample_slot_layout(rng, yaw_range), rng, num_object_points, num_scene_points)


def copy_start_rotation_deg(scenes: list[SlotScene]) -> float:
    """Median rotation error (deg) of the trivial predictor that keeps the start orientation, the box moved
    onto the nearer slot: the baseline an orientation-aware model must beat on these scenes."""
    from lerobot_taxdpd.maths.metrics import rotation_error_deg

    errors = [
        min(float(rotation_error_deg(s.object_points - s.object_points.mean(0) + g.mean(0), g)) for g in s.valid_goals)
        for s in scenes
    ]
    return float(np.median(errors))


def write_slot_dataset(
    root: str | Path,
    repo_id: str = "local/taxdpd_slots",
    *,
    episodes: int = 64,
    frames_per_episode: int = 2,
    object_cloud_size: int = 128,
    scene_cloud_size: int = 256,
    yaw_range: float = math.pi,
    seed: int = 0,
) -> Path:
    """A goal-prediction dataset of the slot task; each episode holds independent samplings of one demo,
    `object_cloud_size` / `scene_cloud_size` points each."""
    rng = np.random.default_rng(seed)
    card = DatasetCardInfo(
        source="synthetic keyed-box-into-slot scenes (lerobot_taxdpd.apps.synthetic)",
        source_license="apache-2.0",
        description="Two-mode synthetic placement task used by the built-in demo and the learning tests.",
        hub_license="apache-2.0",
        details={"seed": str(seed), "yaw_range_rad": f"{yaw_range:.3f}"},
    )
    features = goal_prediction_features(object_cloud_size, scene_cloud_size, with_transform=True)
    with DatasetWriter(repo_id, root, features, fps=GOAL_DATASET_FPS, card=card) as writer:
        for episode in range(episodes):
            layout = sample_slot_layout(rng, yaw_range)
            frames = []
            for _ in range(frames_per_episode):
                scene = render_slot_scene(layout, rng, object_cloud_size, scene_cloud_size)
                frames.append(
                    placement_frame(
                        scene.object_points,
                        scene.scene_points,
                        scene.goal_points,
                        scene.goal_transform,
                        source=f"episode {episode}",
                    )
                )
            writer.add_episode(frames, TASK)
    return Path(root)


def evaluate_slot_predictor(
    predictor,
    *,
    num_scenes: int = 12,
    num_samples: int = 8,
    num_object_points: int = 128,
    num_scene_points: int = 256,
    yaw_range: float = math.pi,
    seed: int = 1234,
    coverage_threshold: float = 0.015,
    **sample_kwargs,
) -> dict[str, float]:
    """Goal-prediction quality on held-out slot scenes (metres and degrees reported as mm and deg).

    Works for anything with `sample_goals` (and `placement_distribution` for the GMM mass). rmse,
    translation and rotation errors score each sample against the slot it went for (medians); wta_rmse is
    the mean over scenes of the best sample's RMSE to the demonstrated goal; coverage counts slots reached
    within `coverage_threshold`; gmm_mass_on_slots sums the mixing weights of components within 2 cm of a
    valid goal centroid.
    """
    import torch

    from lerobot_taxdpd.maths.metrics import point_rmse, score_against_valid_goals

    rng = np.random.default_rng(seed)
    scenes = [make_slot_scene(rng, num_object_points, num_scene_points, yaw_range) for _ in range(num_scenes)]
    obj = torch.from_numpy(np.stack([s.object_points for s in scenes]))
    scene = torch.from_numpy(np.stack([s.scene_points for s in scenes]))
    goals = predictor.sample_goals(obj, scene, num_samples, **sample_kwargs).cpu().numpy()
    coverage, translation, rotation, nearest_rmse, wta_rmse = [], [], [], [], []
    for i, s in enumerate(scenes):
        scores = score_against_valid_goals(goals[i], s.valid_goals)  # each sample against its nearest slot
        coverage.append(float((scores.rmse.min(0) < coverage_threshold).mean()))
        nearest_rmse += scores.nearest_rmse.tolist()
        wta_rmse.append(float(point_rmse(goals[i], s.goal_points).min()))  # vs the demonstrated goal
        translation += scores.translation_error.tolist()
        rotation += scores.rotation_error_deg.tolist()
    result = {
        "rmse_mm": 1000 * float(np.median(nearest_rmse)),
        "wta_rmse_mm": 1000 * float(np.mean(wta_rmse)),
        "translation_error_mm": 1000 * float(np.median(translation)),
        "rotation_error_deg": float(np.median(rotation)),
        f"coverage@{num_samples}": float(np.mean(coverage)),
    }
    if has_placement_distribution(predictor):
        weights, means = predictor.placement_distribution(obj, scene)
        mass = []
        for i, s in enumerate(scenes):
            near = np.linalg.norm(means[i].cpu().numpy()[:, None] - s.valid_goals.mean(1)[None], axis=-1) < 0.02
            mass.append(float(weights[i].cpu().numpy()[near.any(1)].sum()))
        result["gmm_mass_on_slots"] = float(np.mean(mass))
    return result
