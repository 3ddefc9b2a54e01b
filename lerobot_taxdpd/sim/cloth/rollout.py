"""Run one `cloth_hang` episode with any controller, and find the valid goals of a scene.

The goal of a demonstration is where the cloth ends up: its settled shape after the expert has hung it
by hole h on hanger j and let go. The full set of valid goals of a scene is the expert's successful
result for every (hole, hanger) pair, each simulated from the same start.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from lerobot_taxdpd.sim.cloth.env import ClothHangEnv
from lerobot_taxdpd.sim.cloth.expert import ScriptedExpert
from lerobot_taxdpd.sim.cloth.scene import SPLITS, ClothScene

Controller = Callable[[dict[str, np.ndarray]], np.ndarray]


@dataclass
class Episode:
    scene: ClothScene
    success: bool
    success_matrix: np.ndarray  # (holes, hangers)
    pre_release: np.ndarray  # (holes, hangers): hole centroid near the peg's middle when the grippers let go
    start_vertices: np.ndarray  # cloth mesh at the first observation
    final_vertices: np.ndarray  # cloth mesh after release and settling
    seconds: float
    observations: list[dict[str, np.ndarray]] = field(default_factory=list)  # o_t, before action t
    actions: list[np.ndarray] = field(default_factory=list)  # the controller's actions, as the env limits them


def rollout(
    env: ClothHangEnv,
    scene: ClothScene,
    make_controller: Callable[[ClothHangEnv], Controller],
    record: bool = False,
    action_noise: float = 0.0,
    noise_rng: np.random.Generator | None = None,
) -> Episode:
    """Reset to `scene`, act until the env releases the cloth, return what happened.

    `action_noise` > 0 executes each action plus Gaussian noise of that std (metres, per coordinate) while
    the recorded action stays the controller's own (DART): a closed-loop expert then demonstrates how to
    recover from the drift a learnt policy will make.
    """
    if action_noise < 0:
        raise ValueError(f"action_noise: must be >= 0 metres, got {action_noise}")
    if action_noise > 0 and noise_rng is None:
        raise ValueError("action_noise: needs a noise_rng so that the episode can be replayed")
    started = time.perf_counter()
    observation, _ = env.reset(options={"scene": scene})
    start_vertices = env.cloth_vertices()
    controller = make_controller(env)
    observations, actions = [], []
    while True:
        action = np.asarray(controller(observation), dtype=np.float64)
        executed = action + noise_rng.normal(0.0, action_noise, size=6) if action_noise > 0 else action
        next_observation, _, terminated, _, info = env.step(executed)
        if record:
            observations.append(observation)
            actions.append(env.limit_action(action).astype(np.float32))
        observation = next_observation
        if terminated:
            break
    return Episode(
        scene=scene,
        success=info["is_success"],
        success_matrix=info["success_matrix"],
        pre_release=info["pre_release"],
        start_vertices=start_vertices,
        final_vertices=env.cloth_vertices(),
        seconds=time.perf_counter() - started,
        observations=observations,
        actions=actions,
    )


def expert(hole: int, hanger: int) -> Callable[[ClothHangEnv], Controller]:
    """Controller factory of the scripted expert for one (hole, hanger)."""

    def make(env: ClothHangEnv) -> Controller:
        scripted = ScriptedExpert(env, hole, hanger)
        return lambda observation: scripted.act()

    return make


def demo_target(scene: ClothScene) -> tuple[int, int]:
    """The (hole, hanger) a demonstration of this scene aims at: uniform, fixed by the scene's seed."""
    rng = np.random.default_rng([SPLITS.index(scene.split), scene.seed, 2])
    return int(rng.integers(len(scene.holes))), int(rng.integers(len(scene.hangers)))


def valid_goals(
    env: ClothHangEnv,
    scene: ClothScene,
    pairs: Iterable[tuple[int, int]] | None = None,
    stop_after: int | None = None,
) -> dict[tuple[int, int], np.ndarray]:
    """Settled cloth vertices for every (hole, hanger) the expert hangs successfully from this start.

    `pairs` restricts and orders the pairs tried; `stop_after` stops once that many goals are found.
    """
    if pairs is None:
        pairs = [(hole, hanger) for hole in range(len(scene.holes)) for hanger in range(len(scene.hangers))]
    goals = {}
    for hole, hanger in pairs:
        episode = rollout(env, scene, expert(hole, hanger))
        if episode.success_matrix[hole, hanger]:
            goals[hole, hanger] = episode.final_vertices
            if stop_after is not None and len(goals) >= stop_after:
                break
    return goals


def valid_goal_clouds(
    env: ClothHangEnv,
    scene: ClothScene,
    pairs: Iterable[tuple[int, int]] | None = None,
    stop_after: int | None = None,
) -> dict[tuple[int, int], np.ndarray]:
    """`valid_goals` as the clouds a goal sample is scored against (the observed surface points, at the settled
    vertices); leaves `env` reset to the scene's start, where the goal predictor observes it."""
    vertices = valid_goals(env, scene, pairs, stop_after)
    env.reset(options={"scene": scene})
    return {key: env.samples.points(settled, env.mesh.faces) for key, settled in vertices.items()}
