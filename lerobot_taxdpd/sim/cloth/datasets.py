"""The expert's demonstrations as the two LeRobot datasets of the project's schema.

- goal prediction (`taxdpd`): one demo = one episode; each frame is an independent sampling of the
  cloth surface (start cloud, and the same surface points on the settled cloth as the goal) and of the
  hangers, so an episode has `frames_per_episode` >= 2 frames.
- policy (`gc_dp3`): one rollout = one episode, one frame per control step: cloth, hangers, the
  rollout's own goal cloud, gripper state, executed action, `next.done` and `next.success`.

Scene seeds `seed .. seed + episodes - 1` are tried once each; demos the expert fails are skipped and
listed in the dataset card. Workers simulate in parallel processes; the datasets are written in seed
order, so the output does not depend on the number of workers.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import ExitStack
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from lerobot_taxdpd.data.dataset_writer import DatasetCardInfo, DatasetWriter
from lerobot_taxdpd.data.schema import (
    ACTION_KEY,
    DONE_KEY,
    GOAL_CLOUD_KEY,
    GOAL_DATASET_FPS,
    OBJECT_KEY,
    SCENE_KEY,
    STATE_KEY,
    SUCCESS_KEY,
    cloth_policy_features,
    goal_prediction_features,
    placement_frame,
)
from lerobot_taxdpd.sim.cloth.env import TASK_DESCRIPTION, ClothHangEnv, SimSettings
from lerobot_taxdpd.sim.cloth.mesh import sample_surface
from lerobot_taxdpd.sim.cloth.rollout import demo_target, expert, rollout
from lerobot_taxdpd.sim.cloth.scene import SPLITS, hanger_surface_points, sample_scene

DATASET_KINDS = ("goal", "policy", "both")


@dataclass
class Demo:
    seed: int
    hole: int
    hanger: int
    success: bool
    seconds: float
    goal_frames: list[dict[str, np.ndarray]]
    policy_frames: list[dict[str, np.ndarray]]


@dataclass(frozen=True)
class DemoRequest:
    split: str
    seed: int
    frames_per_episode: int
    object_cloud_size: int
    scene_cloud_size: int
    want_goal: bool
    want_policy: bool
    action_noise: float = 0.0


def simulate_demo(request: DemoRequest) -> Demo:
    """One expert demonstration of scene `seed`, turned into frames of the requested datasets."""
    env = ClothHangEnv(request.split, request.object_cloud_size, request.scene_cloud_size)
    try:
        scene = sample_scene(request.split, request.seed, env.ranges)
        hole, hanger = demo_target(scene)
        noise_rng = np.random.default_rng([SPLITS.index(request.split), request.seed, 4])
        episode = rollout(
            env, scene, expert(hole, hanger), record=request.want_policy,
            action_noise=request.action_noise, noise_rng=noise_rng,
        )
        demo = Demo(request.seed, hole, hanger, episode.success, episode.seconds, [], [])
        if not episode.success:
            return demo
        if request.want_goal:
            demo.goal_frames = _goal_frames(env, episode.start_vertices, episode.final_vertices, request)
        if request.want_policy:
            goal = env.samples.points(episode.final_vertices, env.mesh.faces).astype(np.float32)
            last = len(episode.actions) - 1
            demo.policy_frames = [
                {
                    OBJECT_KEY: observation[OBJECT_KEY],
                    SCENE_KEY: observation[SCENE_KEY],
                    GOAL_CLOUD_KEY: goal,
                    STATE_KEY: observation[STATE_KEY],
                    ACTION_KEY: action,
                    DONE_KEY: np.array([t == last]),
                    SUCCESS_KEY: np.array([t == last]),
                }
                for t, (observation, action) in enumerate(zip(episode.observations, episode.actions, strict=True))
            ]
        return demo
    finally:
        env.close()


def _goal_frames(env: ClothHangEnv, start: np.ndarray, final: np.ndarray, request: DemoRequest) -> list[dict]:
    """`frames_per_episode` independent samplings of (start cloud, hangers, goal cloud), rows in correspondence."""
    rng = np.random.default_rng([SPLITS.index(request.split), request.seed, 3])
    frames = []
    for view in range(request.frames_per_episode):
        samples = sample_surface(env.mesh, request.object_cloud_size, rng)
        frames.append(
            placement_frame(
                samples.points(start, env.mesh.faces),
                hanger_surface_points(env.scene.hangers, request.scene_cloud_size, rng),
                samples.points(final, env.mesh.faces),
                source=f"cloth_hang {request.split} seed {request.seed} view {view}",
            )
        )
    return frames


def simulate_demos(requests: list[DemoRequest], workers: int) -> Iterator[Demo]:
    """Demos in request order, simulated by `workers` processes."""
    if workers <= 1:
        yield from map(simulate_demo, requests)
        return
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
        yield from pool.map(simulate_demo, requests)


def generate(
    *,
    split: str,
    seed: int,
    episodes: int,
    root: Path,
    repo_id: str,
    kind: str = "both",
    frames_per_episode: int = 4,
    object_cloud_size: int = 512,
    scene_cloud_size: int = 512,
    workers: int = 1,
    action_noise: float = 0.0,
    overwrite: bool = False,
    command: str | None = None,
    progress: bool = True,
) -> dict[str, object]:
    """Write the goal-prediction and/or policy dataset; returns a summary (counts, paths, timings)."""
    if kind not in DATASET_KINDS:
        raise ValueError(f"dataset: must be one of {DATASET_KINDS}, got {kind!r}")
    if episodes < 1:
        raise ValueError(f"episodes: must be at least 1, got {episodes}")
    if action_noise < 0:
        raise ValueError(f"--action-noise: must be >= 0 metres, got {action_noise}")
    if frames_per_episode < 2:
        raise ValueError(
            f"--frames-per-episode: a goal-prediction episode needs at least 2 frames, got {frames_per_episode}"
        )
    want_goal, want_policy = kind in ("goal", "both"), kind in ("policy", "both")
    paths = _dataset_paths(Path(root), repo_id, kind)
    card = DatasetCardInfo(
        source="lerobot_taxdpd cloth_hang task (pybullet), scripted expert",
        source_license="Apache-2.0 (generated by lerobot_taxdpd)",
        command=command,
        tags=["cloth", "deformable", "pybullet", "simulation"],
        hub_license="apache-2.0",
        details={
            "split": split,
            "scene seeds": f"{seed}..{seed + episodes - 1}",
            "expert action noise (DART, metres)": action_noise,
        },
    )
    requests = [
        DemoRequest(
            split, s, frames_per_episode, object_cloud_size, scene_cloud_size, want_goal, want_policy, action_noise
        )
        for s in range(seed, seed + episodes)
    ]
    seconds, successes = [], 0
    with ExitStack() as stack:
        writers = {}
        if want_goal:
            features = goal_prediction_features(object_cloud_size, scene_cloud_size, with_transform=False)
            writers["goal"] = DatasetWriter(
                *paths["goal"], features, fps=GOAL_DATASET_FPS, card=replace(card, description=_GOAL_DESCRIPTION),
                overwrite=overwrite,
            )
        if want_policy:
            features = cloth_policy_features(object_cloud_size, scene_cloud_size)
            writers["policy"] = DatasetWriter(
                *paths["policy"], features, fps=round(1.0 / SimSettings().control_period),
                card=replace(card, description=_POLICY_DESCRIPTION), overwrite=overwrite,
            )
        for writer in writers.values():
            stack.enter_context(writer)
        demos = simulate_demos(requests, workers)
        for demo in tqdm(demos, total=len(requests), desc="cloth_hang demos", disable=not progress):
            seconds.append(demo.seconds)
            if not demo.success:
                source = f"{split} seed {demo.seed} (hole {demo.hole}, hanger {demo.hanger})"
                for writer in writers.values():
                    writer.skip(source, "the scripted expert did not hang the cloth")
                continue
            successes += 1
            if want_goal:
                writers["goal"].add_episode(demo.goal_frames, task=TASK_DESCRIPTION)
            if want_policy:
                writers["policy"].add_episode(demo.policy_frames, task=TASK_DESCRIPTION)
    return {
        "split": split,
        "episodes_tried": episodes,
        "episodes_written": successes,
        "expert_success_rate": successes / episodes,
        "median_seconds_per_episode": float(np.median(seconds)),
        "datasets": {name: str(path) for name, (_, path) in paths.items()},
    }


def _dataset_paths(root: Path, repo_id: str, kind: str) -> dict[str, tuple[str, Path]]:
    """(repo_id, folder) per dataset: one dataset goes to `root`; both go to `root/goal` and `root/policy`."""
    if kind != "both":
        return {kind: (repo_id, root)}
    return {name: (f"{repo_id}_{name}", root / name) for name in ("goal", "policy")}


_GOAL_DESCRIPTION = (
    "Goal prediction for hanging a procedurally generated cloth by one of its holes on one of two hangers. "
    "Each episode is one expert demonstration; its frames are independent samplings of the cloth surface "
    "(row i of the start cloud and of the goal cloud are the same surface point) and of the hangers."
)
_POLICY_DESCRIPTION = (
    "Expert rollouts of the cloth-hanging task for a goal-conditioned 3D diffusion policy: cloth and hanger "
    "clouds, the rollout's settled goal cloud, both grippers' positions and velocities (12-d) and their "
    "position deltas (6-d) per control step."
)
