"""The simulation's building blocks against real pybullet: geometry splits, bodies, cameras, controller,
upside-down test, and the shared helpers they added (quaternions, coverage from an RMSE matrix)."""

from __future__ import annotations

import itertools

import numpy as np
import pybullet as pb
import pytest

from lerobot_taxdpd.maths.geometry import matrix_to_quaternion_xyzw, quaternion_xyzw_to_matrix
from lerobot_taxdpd.maths.metrics import coverage_precision, coverage_precision_from_rmse, pairwise_rmse
from lerobot_taxdpd.sim.bodies import box, create_body, cylinder, prism
from lerobot_taxdpd.sim.cameras import CameraSpec, orbit_cameras, render_segmented_clouds
from lerobot_taxdpd.sim.controller import penetration, sweep_to_goal
from lerobot_taxdpd.sim.designs.cabinets import CABINET_SPACE, CAN_SPACE
from lerobot_taxdpd.sim.designs.connectors import BUILDERS as CONNECTOR_BUILDERS
from lerobot_taxdpd.sim.designs.connectors import DSUB_SPACE, SSD_SPACE, WATERPROOF_SPACE
from lerobot_taxdpd.sim.designs.connectors import SPACES as CONNECTOR_SPACES
from lerobot_taxdpd.sim.designs.mugs import MUG_SPACE
from lerobot_taxdpd.sim.designs.racks import RACK_SPACE
from lerobot_taxdpd.sim.designs.shelves import BOOK_SPACE, SHELF_SPACE
from lerobot_taxdpd.sim.poses import transform
from lerobot_taxdpd.sim.splits import SPLIT_MARGIN
from lerobot_taxdpd.sim.success import upside_down_test
from lerobot_taxdpd.sim.world import add_table, physics_world

SPACES = [
    MUG_SPACE,
    RACK_SPACE,
    BOOK_SPACE,
    SHELF_SPACE,
    CAN_SPACE,
    CABINET_SPACE,
    WATERPROOF_SPACE,
    DSUB_SPACE,
    SSD_SPACE,
]


@pytest.mark.parametrize("space", SPACES, ids=lambda s: s.name)
def test_held_out_geometry_never_overlaps_training_geometry(space):
    rng = np.random.default_rng(0)
    train = [space.sample(rng, "train") for _ in range(300)]
    test = [space.sample(rng, "test") for _ in range(300)]
    assert all(space.split_of(p) == "train" for p in train) and all(space.split_of(p) == "test" for p in test)
    train_keys = np.stack([space.unit_keys(p) for p in train])
    test_keys = np.stack([space.unit_keys(p) for p in test])
    # Chebyshev distance between every train and every test shape in the split keys' unit square.
    gaps = np.abs(train_keys[:, None] - test_keys[None]).max(-1)
    assert gaps.min() >= 2 * SPLIT_MARGIN - 1e-9
    # Both splits span (nearly) the whole range of both keys: the test is unseen shapes, not extrapolation.
    for keys in (train_keys, test_keys):
        assert (keys.min(0) < 0.15).all() and (keys.max(0) > 0.85).all()
    for params in train + test:
        for name, (low, high) in space.ranges.items():
            assert low <= params[name] <= high


def test_a_bad_split_is_named():
    with pytest.raises(ValueError, match="split"):
        MUG_SPACE.sample(np.random.default_rng(0), "validation")


def test_quaternion_round_trip_including_half_turns():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1
    np.testing.assert_allclose(matrix_to_quaternion_xyzw(quaternion_xyzw_to_matrix(q)), q, atol=1e-9)
    for axis in np.eye(3):
        rotation = quaternion_xyzw_to_matrix(np.r_[axis, 0.0])
        np.testing.assert_allclose(quaternion_xyzw_to_matrix(matrix_to_quaternion_xyzw(rotation)), rotation, atol=1e-12)


def test_coverage_from_an_rmse_matrix_matches_the_cloud_version():
    rng = np.random.default_rng(2)
    samples, goals = rng.normal(size=(6, 20, 3)), rng.normal(size=(3, 20, 3))
    goals[1] = samples[2] + 0.001
    direct = coverage_precision(samples, goals, 0.05)
    assert coverage_precision_from_rmse(pairwise_rmse(samples, goals), 0.05) == direct
    assert direct["coverage"] == pytest.approx(1 / 3) and direct["precision"] == pytest.approx(1 / 6)


def test_bodies_collide_exactly_at_clearance_scale():
    """Distances are exact to the micrometre, including a prism, and beyond Bullet's 16-child limit."""
    with physics_world() as client:
        wall = create_body(client, [box((0.002, 0.03, 0.03))], position=(0.0, 0.0, 0.0))
        many = [box((0.002, 0.002, 0.002), position=(0.0, 0.0, 0.01 * i)) for i in range(20)]  # 20 > 16 children
        column = create_body(client, many, mass=0.1, position=(0.0023, 0.0, -0.15))
        # Only the top box (the 20th part) reaches the wall's height band: it must still collide.
        hits = pb.getClosestPoints(column, wall, 0.01, physicsClientId=client)
        assert min(p[8] for p in hits) == pytest.approx(-0.0017, abs=1e-6)
        outline = np.array([[-0.01, -0.004], [0.01, -0.004], [0.008, 0.004], [-0.008, 0.004]])
        plug = create_body(client, [prism(outline, 0.0, 0.01), cylinder(0.012, 0.01, position=(0, 0, 0.02))], mass=0.02)
        pb.resetBasePositionAndOrientation(
            plug, (0.002 + 0.01 + 0.0003, 0.0, -0.005), (0, 0, 0, 1), physicsClientId=client
        )
        distances = [p[8] for p in pb.getClosestPoints(plug, wall, 0.005, linkIndexA=-1, physicsClientId=client)]
        assert min(distances) == pytest.approx(0.0003, abs=2e-6)


@pytest.mark.parametrize("family", sorted(CONNECTOR_BUILDERS))
def test_every_corner_of_a_connector_space_builds_solid_bodies(family):
    """The extremes of the parameters meet (narrowest SSD card with its notch farthest out, ...): every
    combination must still give plug and socket parts Bullet can collide, or demo generation stops there."""
    space = CONNECTOR_SPACES[family]
    names = list(space.ranges)
    with physics_world() as client:
        for corner in itertools.product(*(space.ranges[name] for name in names)):
            plug, socket = CONNECTOR_BUILDERS[family](dict(zip(names, corner, strict=True)))
            create_body(client, list(plug.parts), mass=0.02)
            create_body(client, list(socket.parts))


def test_parts_thinner_than_bullets_margin_are_refused_unless_drawn_only():
    with physics_world() as client:
        with pytest.raises(ValueError, match="thinner than 2 mm"):
            create_body(client, [box((0.01, 0.01, 0.0005))])
        create_body(client, [box((0.01, 0.01, 0.01)), cylinder(0.0005, 0.001, collides=False)])


def test_cameras_give_exact_fused_partial_clouds_of_the_requested_body_only():
    with physics_world() as client:
        table = add_table(client)
        block = create_body(client, [box((0.05, 0.03, 0.02))], position=(0.1, 0.2, 0.02))
        cameras = orbit_cameras((0.1, 0.2, 0.02), 0.4, 35.0, (0.0, 120.0, 240.0), width=160, height=120)
        clouds = render_segmented_clouds(client, cameras, [block])
        points = clouds[block]
        assert table not in clouds and len(points) > 1000
        local = points - np.array([0.1, 0.2, 0.02])
        top = local[(np.abs(local[:, 0]) < 0.045) & (np.abs(local[:, 1]) < 0.025) & (local[:, 2] > 0.0)]
        assert len(top) > 300 and np.abs(top[:, 2] - 0.02).max() < 1e-5  # the top face, exactly at its height
        assert (np.abs(local) <= np.array([0.05, 0.03, 0.02]) + 1e-4).all()
        inner = (np.abs(local[:, 0]) < 0.045) & (np.abs(local[:, 1]) < 0.025)
        assert not (inner & (local[:, 2] < 0.0)).any()  # the bottom face rests on the table, unseen: a partial view
        single = render_segmented_clouds(client, cameras[:1], [block])[block]
        assert len(single) < len(points)  # each camera adds unseen parts
    with pytest.raises(ValueError, match="parallel"):
        CameraSpec(eye=(0.0, 0.0, 1.0), target=(0.0, 0.0, 0.0))


def test_controller_stops_at_the_first_contact_and_refuses_to_start_inside_an_obstacle():
    with physics_world() as client:
        wall = create_body(client, [box((0.01, 0.1, 0.1))], position=(0.0, 0.0, 0.2))
        cube = create_body(client, [box((0.01, 0.01, 0.01))], mass=0.1)
        goal = transform(translation=(0.0, 0.0, 0.2))  # inside the wall
        result = sweep_to_goal(
            client,
            cube,
            goal,
            np.array([1.0, 0.0, 0.0]),
            0.1,
            [wall],
            coarse_step=0.005,
            fine_step=0.0002,
            tolerance=0.0001,
        )
        assert not result.reached_goal and result.started
        assert result.pose[0, 3] == pytest.approx(-0.02, abs=0.0003)  # faces touching, within one fine step
        assert penetration(client, cube, [wall]) <= 0.0001
        deep = sweep_to_goal(
            client,
            cube,
            goal,
            np.array([1.0, 0.0, 0.0]),
            0.005,
            [wall],
            coarse_step=0.005,
            fine_step=0.0002,
            tolerance=0.0001,
        )
        assert not deep.started


def test_upside_down_test_frees_resting_objects_and_rejects_wedged_ones():
    def run(overlap: float) -> bool:
        with physics_world() as client:
            table = add_table(client)
            holder = create_body(
                client,
                [
                    box((0.05, 0.05, 0.005), (0, 0, 0.005)),
                    box((0.005, 0.05, 0.04), (-0.025, 0, 0.05)),
                    box((0.005, 0.05, 0.04), (0.025, 0, 0.05)),
                ],
            )
            block = create_body(client, [box((0.02 + overlap, 0.02, 0.02))], mass=0.2, position=(0.0, 0.0, 0.0301))
            return upside_down_test(client, block, [holder], table)

    assert run(0.0)  # rests between the walls: falls out when flipped
    assert not run(0.003)  # 3 mm into each wall: wedged
