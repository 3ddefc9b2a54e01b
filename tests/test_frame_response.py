"""`benchmarks/frame_response.py`: the slope of where samples land against where their frame is put reads 1 for a
predictor that stays at its frame and 0 for one that finds the goal from anywhere."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from lerobot_taxdpd.sim.tasks import get_task
from lerobot_taxdpd.sim.trials import make_trial

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import frame_response  # noqa: E402


class _Demonstrated:
    """The demonstrated goal, moved to the frame it is given (`follows_frame`) or left where it is."""

    def __init__(self, trial, follows_frame: bool) -> None:
        self.goal = torch.from_numpy(trial.goal_points().astype(np.float64))
        self.follows_frame = follows_frame

    def sample_goals(self, object_points, scene_points, num_samples, *, generator=None, placement_frames=None):
        goal = self.goal
        if self.follows_frame:
            goal = goal - goal.mean(0) + placement_frames[0]
        return goal.expand(1, num_samples, *goal.shape)


@pytest.fixture(scope="module")
def trial():
    return make_trial(get_task("book_shelf"), 1000)


@pytest.mark.parametrize("follows_frame", [True, False], ids=["stays-at-its-frame", "finds-the-goal"])
def test_the_slope_says_how_much_of_the_frames_offset_passes_through(trial, follows_frame):
    offsets_mm = np.linspace(-13.0, 13.0, 5)
    landings = frame_response.landing_offsets(_Demonstrated(trial, follows_frame), trial, offsets_mm / 1000, 2, 0)
    summary = frame_response.summarise(landings[None], offsets_mm)
    for row in summary.values():
        assert row["slope"] == pytest.approx(1.0 if follows_frame else 0.0, abs=1e-6)
        assert row["true_frame_error_median_mm"] == pytest.approx(0.0, abs=1e-6)
