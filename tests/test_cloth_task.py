"""The cloth_hang task: procedural cloth rules, scenes and splits, the pybullet env and the success check."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lerobot_taxdpd.data.schema import OBJECT_KEY, SCENE_KEY, STATE_KEY
from lerobot_taxdpd.sim.cloth import checks
from lerobot_taxdpd.sim.cloth.env import ClothHangEnv
from lerobot_taxdpd.sim.cloth.mesh import MIN_EDGE_INDEX, Hole, build_cloth_mesh, sample_holes, sample_surface
from lerobot_taxdpd.sim.cloth.scene import Hanger, is_test_hole, sample_scene


@pytest.mark.parametrize("num_holes", [1, 2])
def test_holes_follow_dedo_rules(num_holes):
    rng = np.random.default_rng(0)
    n = 15
    for _ in range(200):
        holes = sample_holes(rng, n, num_holes)
        assert len(holes) == num_holes
        for hole in holes:
            assert MIN_EDGE_INDEX <= hole.x0 < hole.x1 <= n - 1 - MIN_EDGE_INDEX
            assert MIN_EDGE_INDEX <= hole.y0 < hole.y1 <= n - 1 - MIN_EDGE_INDEX
            assert hole.x1 - hole.x0 <= round(0.3 * n) - 1
        if num_holes == 2:
            a, b = holes
            gap_x = max(b.x0 - a.x1, a.x0 - b.x1)
            gap_y = max(b.y0 - a.y1, a.y0 - b.y1)
            assert max(gap_x, gap_y) >= 3, holes


def test_mesh_removes_holes_and_keeps_loops_closed():
    holes = [Hole(4, 6, 3, 5), Hole(9, 10, 9, 11)]
    mesh = build_cloth_mesh(15, 2.4, 2.0, holes)
    removed = sum((h.x1 - h.x0 + 1) * (h.y1 - h.y0 + 1) for h in holes)
    assert len(mesh.vertices) == 15 * 15 - removed
    assert set(np.unique(mesh.faces)) == set(range(len(mesh.vertices))), "every kept node is in a triangle"
    assert mesh.vertices[mesh.corner_vertices[0]].tolist() == pytest.approx([-1.2, 0.0, 0.0])
    assert mesh.vertices[mesh.corner_vertices[1]].tolist() == pytest.approx([1.2, 0.0, 0.0])
    for hole, loop in zip(holes, mesh.hole_loops, strict=True):
        ring = mesh.vertices[loop]
        assert len(loop) == 2 * (hole.x1 - hole.x0 + 2) + 2 * (hole.y1 - hole.y0 + 2)
        steps = np.linalg.norm(np.diff(np.vstack([ring, ring[:1]]), axis=0), axis=1)
        assert steps.max() == pytest.approx(2.4 / 14), "consecutive loop nodes are grid neighbours"
        # The hole's interior lies inside its loop (in the cloth plane x-z).
        centre = ring.mean(axis=0)
        assert checks.winding_number(ring[:, [0, 2]], centre[[0, 2]]) != 0


def test_mesh_rejects_a_hole_at_the_edge():
    with pytest.raises(ValueError, match="holes"):
        build_cloth_mesh(15, 2.0, 2.0, [Hole(1, 3, 5, 6)])


def test_surface_samples_follow_the_material_under_deformation():
    mesh = build_cloth_mesh(15, 2.0, 2.0, [Hole(5, 7, 5, 7)])
    samples = sample_surface(mesh, 512, np.random.default_rng(1))
    rest = samples.points(mesh.vertices, mesh.faces)
    assert rest.shape == (512, 3)
    assert len(np.unique(rest.round(6), axis=0)) == 512
    # Points lie on the cloth, never inside the hole.
    u, v = rest[:, 0] / 2.0 + 0.5, -rest[:, 2] / 2.0
    in_hole = (u > 5 / 14 + 1e-6) & (u < 7 / 14 - 1e-6) & (v > 5 / 14 + 1e-6) & (v < 7 / 14 - 1e-6)
    assert not in_hole.any()
    # A rigid motion of the mesh moves every sample rigidly: rows keep their meaning.
    angle = 0.7
    rotation = np.array([[math.cos(angle), -math.sin(angle), 0], [math.sin(angle), math.cos(angle), 0], [0, 0, 1]])
    moved = samples.points(mesh.vertices @ rotation.T + [1.0, 2.0, 3.0], mesh.faces)
    np.testing.assert_allclose(moved, rest @ rotation.T + [1.0, 2.0, 3.0], atol=1e-9)


def test_scenes_are_reproducible_and_splits_hold_out_hole_shapes():
    assert sample_scene("train", 7) == sample_scene("train", 7)
    assert sample_scene("train", 7) != sample_scene("test", 7)
    for seed in range(40):
        train, test = sample_scene("train", seed), sample_scene("test", seed)
        assert not any(is_test_hole(h) for h in train.holes)
        assert all(is_test_hole(h) for h in test.holes)
        for scene in (train, test):
            a, b = scene.hangers
            assert math.hypot(a.x - b.x, a.y - b.y) >= 4.0
            assert a.x <= b.x
    with pytest.raises(ValueError, match="split"):
        sample_scene("val", 0)


def test_peg_check_needs_the_peg_through_the_loop():
    hanger = Hanger(x=0.0, y=0.0, yaw=0.4, peg_height=4.5)
    axis = hanger.peg_direction
    u = np.cross(axis, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    angles = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    ring = 0.3 * (np.cos(angles)[:, None] * u + np.sin(angles)[:, None] * v)
    assert checks.loop_encircles_peg(hanger.goal_point + ring, hanger)
    assert not checks.loop_encircles_peg(hanger.goal_point + ring + 0.5 * u, hanger), "peg beside the loop"
    assert not checks.loop_encircles_peg(hanger.peg_tip + 0.5 * axis + ring, hanger), "loop beyond the tip"


@pytest.fixture(scope="module")
def env():
    environment = ClothHangEnv(split="train")
    yield environment
    environment.close()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_env_builds_and_steps(env, seed):
    observation, info = env.reset(seed=seed)
    assert observation[OBJECT_KEY].shape == (512, 3) and observation[OBJECT_KEY].dtype == np.float32
    assert observation[SCENE_KEY].shape == (512, 3)
    assert observation[STATE_KEY].shape == (12,)
    assert all(np.isfinite(v).all() for v in observation.values())
    assert info["hole_centroids"].shape == (len(env.scene.holes), 3)
    grippers = env.gripper_positions()
    # The cloth hangs below its grippers, the hangers stand on the ground.
    assert observation[OBJECT_KEY][:, 2].max() <= grippers[:, 2].max() + 0.05
    assert observation[SCENE_KEY][:, 2].min() == pytest.approx(0.0, abs=0.02)
    action = np.array([0.05, 0.0, 0.0, 0.0, 0.0, 0.3], dtype=np.float32)  # the second is clipped to 0.08 m
    observation, reward, terminated, truncated, info = env.step(action)
    moved = env.gripper_positions() - grippers
    np.testing.assert_allclose(moved[0], [0.05, 0, 0], atol=1e-9)
    np.testing.assert_allclose(moved[1], [0, 0, env.settings.max_gripper_step], atol=1e-9)
    np.testing.assert_allclose(info["applied_action"], moved.reshape(6), atol=1e-6)
    np.testing.assert_allclose(observation[STATE_KEY][6:9], [0.05 / env.settings.control_period, 0, 0], rtol=1e-5)
    assert not terminated and not truncated and reward == 0.0


def test_env_rejects_bad_actions(env):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(np.zeros(5))
    with pytest.raises(ValueError, match="action"):
        env.step(np.array([np.nan, 0, 0, 0, 0, 0]))


def test_simulation_is_deterministic_within_a_process(env):
    def run() -> np.ndarray:
        env.reset(seed=4)
        for _ in range(10):
            env.step(np.array([0.03, -0.05, 0.0, 0.03, -0.05, 0.0]))
        return env.cloth_vertices()

    np.testing.assert_array_equal(run(), run())


def test_released_cloth_falls_and_the_episode_ends(env):
    env.reset(seed=3)
    info = env.release()
    assert not info["is_success"], "a cloth dropped where it starts hangs on nothing"
    assert info["success_matrix"].shape == (len(env.scene.holes), 2)
    assert env.cloth_vertices()[:, 2].min() < 0.3, "the cloth fell to the ground"
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(6))


def test_simulated_hangers_match_their_analytic_geometry(env):
    """The physics bodies, the hanger cloud and the success check all describe the same pegs."""
    import pybullet as pb

    env.reset(seed=5)
    for hanger in env.scene.hangers:
        outside = hanger.peg_tip + 0.5 * hanger.peg_direction
        hit = pb.rayTest(outside.tolist(), hanger.peg_root.tolist(), physicsClientId=env._client)[0]
        np.testing.assert_allclose(hit[3], hanger.peg_tip, atol=0.02)
        top = np.array([hanger.x, hanger.y, hanger.pole_height])
        hit = pb.rayTest((top + [0, 0, 1.0]).tolist(), (top - [0, 0, 1.0]).tolist(), physicsClientId=env._client)[0]
        np.testing.assert_allclose(hit[3], top, atol=0.02)
        distances = np.linalg.norm(env.hanger_points[:, None] - hanger.peg_tip, axis=-1)
        assert distances.min() < 0.1, "the hanger cloud covers the peg tip"
