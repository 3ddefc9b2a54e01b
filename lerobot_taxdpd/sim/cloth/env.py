"""The `cloth_hang` task: pybullet (DIRECT, headless) mass-spring cloth held at two corners by grippers.

An action is the two grippers' position deltas (6-d, metres per control step). After
`max_episode_steps` actions the grippers let go, the cloth settles, and the episode ends with DEDO's
success check. Observations are clouds sampled on the simulation mesh (a fixed set of surface points per
episode, so rows keep their meaning over time), points on the hangers, and the grippers' positions and
velocities (12-d).
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pybullet as p

from lerobot_taxdpd.data.schema import DEFAULT_POINT_COUNTS, OBJECT_KEY, SCENE_KEY, STATE_KEY
from lerobot_taxdpd.sim.cloth import checks
from lerobot_taxdpd.sim.cloth.mesh import ClothMesh, SurfaceSamples, build_cloth_mesh, sample_surface, write_obj
from lerobot_taxdpd.sim.cloth.scene import (
    SPLITS,
    ClothScene,
    Hanger,
    SceneRanges,
    hanger_surface_points,
    sample_scene,
)

TASK_DESCRIPTION = "hang the cloth by one of its holes on the peg of one of the hangers"


@dataclass(frozen=True)
class SimSettings:
    """Physics and control constants.

    DEDO's cloth has elastic 50, bending 1, damping 0.01, friction 0.1 and self-collision. Two changes,
    both measured (docs/cloth.md): damping 0.5 in all directions, because at this scale 0.01 leaves the cloth
    swinging for many seconds; self-collision off, because with it pybullet's soft-body solver does not
    replay a scene identically within one process.
    """

    time_step: float = 1.0 / 500.0
    substeps_per_action: int = 25  # 20 Hz control
    max_episode_steps: int = 200
    start_settle_steps: int = 250  # let the freshly loaded cloth sag before the first observation
    release_settle_steps: int = 500  # DEDO checks 500 steps after release
    max_gripper_step: float = 0.08  # metres per action and gripper (1.6 m/s)
    cloth_mass: float = 1.0
    elastic_stiffness: float = 50.0
    damping_stiffness: float = 0.5
    damp_all_directions: bool = True
    bending_stiffness: float = 1.0
    friction: float = 0.1
    collision_margin: float = 0.06
    self_collision: bool = False
    success_radius: float = 0.6  # hole centroid to goal point before release

    @property
    def control_period(self) -> float:
        return self.time_step * self.substeps_per_action


def cloth_world_vertices(mesh: ClothMesh, scene: ClothScene) -> np.ndarray:
    """Rest mesh placed at the scene's start pose (top edge centred on `cloth_center`, turned by `cloth_yaw`)."""
    c, s = math.cos(scene.cloth_yaw), math.sin(scene.cloth_yaw)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return mesh.vertices @ rotation.T + np.asarray(scene.cloth_center)


class ClothHangEnv(gym.Env):
    """Gymnasium env of the cloth-hanging task. `reset(seed=k)` builds scene k of the env's split;
    `reset(options={"scene": scene})` replays a given scene."""

    metadata = {"render_modes": []}

    def __init__(
        self,
        split: str = "train",
        object_cloud_size: int = DEFAULT_POINT_COUNTS["cloth_hang"][0],
        scene_cloud_size: int = DEFAULT_POINT_COUNTS["cloth_hang"][1],
        settings: SimSettings | None = None,
        ranges: SceneRanges | None = None,
    ) -> None:
        for name, value in (("object_cloud_size", object_cloud_size), ("scene_cloud_size", scene_cloud_size)):
            if value < 3:
                raise ValueError(f"{name}: need at least 3 points, got {value}")
        self.split = split
        self.object_cloud_size = object_cloud_size
        self.scene_cloud_size = scene_cloud_size
        self.settings = settings or SimSettings()
        self.ranges = ranges or SceneRanges()
        self.observation_space = gym.spaces.Dict(
            {
                OBJECT_KEY: gym.spaces.Box(-np.inf, np.inf, (object_cloud_size, 3), np.float32),
                SCENE_KEY: gym.spaces.Box(-np.inf, np.inf, (scene_cloud_size, 3), np.float32),
                STATE_KEY: gym.spaces.Box(-np.inf, np.inf, (12,), np.float32),
            }
        )
        limit = self.settings.max_gripper_step
        self.action_space = gym.spaces.Box(-limit, limit, (6,), np.float32)
        self._client = p.connect(p.DIRECT)
        self.scene: ClothScene | None = None
        self.mesh: ClothMesh | None = None
        self.samples: SurfaceSamples | None = None
        self.hanger_points: np.ndarray | None = None
        self._cloth = -1
        self._grippers: list[int] = []
        self._anchors: list[int] = []
        self._velocity = np.zeros(6)
        self._steps = 0
        self._released = False
        self._builds = 0

    # ------------------------------------------------------------------------------------- episode
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        scene = (options or {}).get("scene")
        if scene is None:
            if seed is None:
                seed = int(self.np_random.integers(2**31))
            scene = sample_scene(self.split, seed, self.ranges)
        self._build(scene)
        self._simulate(self.settings.start_settle_steps)
        return self.observation(), self._info()

    def step(self, action):
        if self.scene is None:
            raise RuntimeError("call reset() before step()")
        if self._released:
            raise RuntimeError("the episode is over (the grippers released the cloth); call reset()")
        delta = np.asarray(action, dtype=np.float64)
        if delta.shape != (6,) or not np.isfinite(delta).all():
            raise ValueError(f"action: expected 6 finite gripper deltas (metres), got shape {delta.shape}")
        delta = self.limit_action(delta).reshape(2, 3)
        start = self.gripper_positions()
        n = self.settings.substeps_per_action
        for k in range(1, n + 1):
            for body, position in zip(self._grippers, start + delta * (k / n), strict=True):
                p.resetBasePositionAndOrientation(body, position.tolist(), [0, 0, 0, 1], physicsClientId=self._client)
            p.stepSimulation(physicsClientId=self._client)
        self._velocity = (delta / self.settings.control_period).reshape(6)
        self._steps += 1
        terminated = self._steps >= self.settings.max_episode_steps
        info = self._info()
        info["applied_action"] = delta.reshape(6).astype(np.float32)
        if terminated:
            info.update(self.release())
        return self.observation(), float(info.get("is_success", False)), terminated, False, info

    def release(self) -> dict[str, Any]:
        """Let go of the cloth, let it settle and check success (DEDO: 500 steps after release)."""
        vertices = self.cloth_vertices()
        radius = self.settings.success_radius
        pre = checks.pre_release_matrix(vertices, self.mesh.hole_loops, self.scene.hangers, radius)
        for anchor in self._anchors:
            p.removeConstraint(anchor, physicsClientId=self._client)
        self._anchors = []
        self._released = True
        self._velocity = np.zeros(6)
        self._simulate(self.settings.release_settle_steps)
        post = checks.post_release_matrix(self.cloth_vertices(), self.mesh.hole_loops, self.scene.hangers)
        success = pre & post
        return {"pre_release": pre, "post_release": post, "success_matrix": success, "is_success": bool(success.any())}

    def close(self) -> None:
        if self._client is not None and p.isConnected(self._client):
            p.disconnect(self._client)
        self._client = None

    # -------------------------------------------------------------------------------- observations
    def observation(self) -> dict[str, np.ndarray]:
        return {
            OBJECT_KEY: self.cloth_points().astype(np.float32),
            SCENE_KEY: self.hanger_points.astype(np.float32),
            STATE_KEY: self.state(),
        }

    def state(self) -> np.ndarray:
        """Both grippers' positions then velocities (m, m/s), 12-d float32."""
        return np.concatenate([self.gripper_positions().reshape(6), self._velocity]).astype(np.float32)

    def cloth_points(self, samples: SurfaceSamples | None = None) -> np.ndarray:
        """The episode's surface points (or `samples`) on the current cloth."""
        return (samples or self.samples).points(self.cloth_vertices(), self.mesh.faces)

    def cloth_vertices(self) -> np.ndarray:
        _, vertices = p.getMeshData(self._cloth, -1, flags=p.MESH_DATA_SIMULATION_MESH, physicsClientId=self._client)
        return np.asarray(vertices, dtype=np.float64)

    def gripper_positions(self) -> np.ndarray:
        return np.array(
            [p.getBasePositionAndOrientation(b, physicsClientId=self._client)[0] for b in self._grippers],
            dtype=np.float64,
        )

    def hole_centroids(self) -> np.ndarray:
        return checks.hole_centroids(self.cloth_vertices(), self.mesh.hole_loops)

    @property
    def hangers(self) -> tuple[Hanger, ...]:
        return self.scene.hangers

    @property
    def elapsed_steps(self) -> int:
        return self._steps

    # ------------------------------------------------------------------------------------ building
    def _build(self, scene: ClothScene) -> None:
        s, cid = self.settings, self._client
        p.resetSimulation(p.RESET_USE_DEFORMABLE_WORLD, physicsClientId=cid)
        p.setGravity(0, 0, -9.8, physicsClientId=cid)
        p.setTimeStep(s.time_step, physicsClientId=cid)
        ground = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid)
        p.createMultiBody(0, ground, physicsClientId=cid)
        for hanger in scene.hangers:
            self._add_hanger(hanger)
        self.scene = scene
        self.mesh = build_cloth_mesh(scene.node_density, scene.cloth_width, scene.cloth_height, list(scene.holes))
        vertices = cloth_world_vertices(self.mesh, scene)
        # pybullet caches meshes by file name: every episode needs a file of its own. The file lives only while it
        # loads, so a process that is killed (a pool's worker) leaves no folder behind.
        self._builds += 1
        with tempfile.TemporaryDirectory(prefix="cloth_hang-") as folder:
            obj = Path(folder) / f"cloth-{self._builds}.obj"
            write_obj(obj, vertices, self.mesh.faces)
            self._cloth = p.loadSoftBody(
                str(obj),
                mass=s.cloth_mass,
                collisionMargin=s.collision_margin,
                useMassSpring=1,
                useBendingSprings=1,
                springElasticStiffness=s.elastic_stiffness,
                springDampingStiffness=s.damping_stiffness,
                springDampingAllDirections=int(s.damp_all_directions),
                springBendingStiffness=s.bending_stiffness,
                frictionCoeff=s.friction,
                useSelfCollision=int(s.self_collision),
                useFaceContact=1,
                physicsClientId=cid,
            )
        self._grippers, self._anchors = [], []
        for vertex in self.mesh.corner_vertices:
            body = p.createMultiBody(0, -1, -1, vertices[vertex].tolist(), physicsClientId=cid)
            self._grippers.append(body)
            self._anchors.append(p.createSoftBodyAnchor(self._cloth, vertex, body, -1, physicsClientId=cid))
        rng = np.random.default_rng([SPLITS.index(scene.split), scene.seed, 1])
        self.samples = sample_surface(self.mesh, self.object_cloud_size, rng)
        self.hanger_points = hanger_surface_points(scene.hangers, self.scene_cloud_size, rng)
        self._velocity = np.zeros(6)
        self._steps = 0
        self._released = False

    def _add_hanger(self, hanger: Hanger) -> None:
        s, cid = hanger.shape, self._client
        tilt = math.radians(s.peg_tilt_deg)
        pole_height = hanger.pole_height
        peg_centre = np.array([0.0, math.cos(tilt), math.sin(tilt)]) * s.peg_length / 2 + [0, 0, hanger.peg_height]
        shape = p.createCollisionShapeArray(
            shapeTypes=[p.GEOM_CYLINDER] * 3,
            radii=[s.base_radius, s.pole_radius, s.peg_radius],
            lengths=[s.base_height, pole_height, s.peg_length],
            collisionFramePositions=[[0, 0, s.base_height / 2], [0, 0, pole_height / 2], peg_centre.tolist()],
            collisionFrameOrientations=[
                [0, 0, 0, 1],
                [0, 0, 0, 1],
                p.getQuaternionFromEuler([tilt - math.pi / 2, 0, 0]),
            ],
            physicsClientId=cid,
        )
        p.createMultiBody(
            0,
            shape,
            basePosition=[hanger.x, hanger.y, 0.0],
            baseOrientation=p.getQuaternionFromEuler([0, 0, hanger.yaw]),
            physicsClientId=cid,
        )

    # ------------------------------------------------------------------------------------- helpers
    def _simulate(self, steps: int) -> None:
        for _ in range(steps):
            p.stepSimulation(physicsClientId=self._client)

    def limit_action(self, action: np.ndarray) -> np.ndarray:
        """The 6-d action the env executes: each gripper's displacement clipped to `max_gripper_step`."""
        delta = np.asarray(action, dtype=np.float64).reshape(2, 3)
        norm = np.linalg.norm(delta, axis=1, keepdims=True)
        return (delta * np.minimum(1.0, self.settings.max_gripper_step / np.maximum(norm, 1e-12))).reshape(6)

    def _info(self) -> dict[str, Any]:
        return {"step": self._steps, "hole_centroids": self.hole_centroids()}
