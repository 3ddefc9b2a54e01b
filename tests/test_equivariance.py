"""The equivariance probe tells a goal that follows the scene from one that copies the object's start pose."""

from __future__ import annotations

import pytest
import torch

from lerobot_taxdpd.maths.equivariance import goal_turn_response


class CopiesTheStartPose:
    """The trap: the goal is the object as it starts, moved to the scene's centre."""

    def sample_goals(self, object_points, scene_points, num_samples, generator=None):
        goal = object_points - object_points.mean(1, keepdim=True) + scene_points.mean(1, keepdim=True)
        return goal[:, None].expand(-1, num_samples, -1, -1)


class FollowsTheScene:
    """A correct predictor in miniature: the goal is fixed to the scene (its first points), whatever the object."""

    def sample_goals(self, object_points, scene_points, num_samples, generator=None):
        return scene_points[:, None, : object_points.shape[1]].expand(-1, num_samples, -1, -1)


@pytest.fixture
def clouds():
    g = torch.Generator().manual_seed(0)
    return torch.randn(3, 40, 3, generator=g), torch.randn(3, 90, 3, generator=g)


def test_a_predictor_that_copies_the_start_pose_turns_with_the_object(clouds):
    turns = goal_turn_response(CopiesTheStartPose(), *clouds, angle_deg=20.0, tilt_deg=10.0)
    assert turns["scene_yaw"] == pytest.approx(0.0, abs=1e-4)
    assert turns["object_yaw"] == pytest.approx(20.0, abs=1e-4)
    assert turns["object_tilt"] == pytest.approx(10.0, abs=1e-4)


def test_a_predictor_that_follows_the_scene_ignores_the_object(clouds):
    turns = goal_turn_response(FollowsTheScene(), *clouds, angle_deg=20.0, tilt_deg=10.0)
    assert turns["scene_yaw"] == pytest.approx(20.0, abs=1e-4)
    assert turns["object_yaw"] == pytest.approx(0.0, abs=1e-4)
    assert turns["object_tilt"] == pytest.approx(0.0, abs=1e-4)


def test_yaw_is_folded_by_the_objects_symmetry(clouds):
    turns = goal_turn_response(CopiesTheStartPose(), *clouds, angle_deg=170.0, symmetry_period_deg=180.0)
    assert turns["object_yaw"] == pytest.approx(-10.0, abs=1e-4)  # 170 deg is 10 deg short of a symmetry
