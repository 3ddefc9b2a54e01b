"""The evaluation harness and its command line, driven by honest reference predictors: the ground truth
(which must succeed and cover every mode) and the ground truth off by a known error (which must fail,
and whose errors the report must measure as exactly that error)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from conftest import run_cli
from lerobot_taxdpd.reports.benchmarking import write_json
from lerobot_taxdpd.sim.cli import main
from lerobot_taxdpd.sim.harness import evaluate
from lerobot_taxdpd.sim.predictors import GoalPredictor, OraclePredictor
from lerobot_taxdpd.sim.tasks import get_task
from lerobot_taxdpd.sim.trials import make_trial

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _trials(name: str, count: int, first_seed: int = 0):
    task = get_task(name)
    return [make_trial(task, seed, "test") for seed in range(first_seed, first_seed + count)]


class OracleWithGMM(OraclePredictor):
    """The oracle plus a Dense-GMM-like map: weight of a scene point ~ exp(-distance to the true goal^2)."""

    def __init__(self, trials):
        super().__init__(trials)
        self._by_cloud = [(t.object_points, t.goal_points().mean(0)) for t in trials]

    def placement_distribution(self, object_points, scene_points):
        cloud = object_points[0].numpy()
        centre = next(c for o, c in self._by_cloud if np.array_equal(o, cloud))
        distance = (scene_points[0] - torch.from_numpy(centre)).norm(dim=-1)
        weights = torch.softmax(-((distance / 0.03) ** 2), dim=0)
        return weights[None], scene_points.clone()


def test_ground_truth_succeeds_covers_every_mode_and_draws_figures(tmp_path):
    trials = _trials("mug_medrack", 3)
    report = evaluate(OracleWithGMM(trials), trials, 4, figures_dir=tmp_path, num_figures=2, progress=False)
    assert report["success"]["success_rate"] == 1.0 and report["success"]["trials"] == 3
    assert report["success"]["ci95_low"] < 1.0 == report["success"]["ci95_high"]
    assert report["translation_error_mm"]["median"] < 1e-3 and report["rotation_error_deg"]["median"] < 1e-3
    assert report["winner_take_all_rmse_mm"]["median"] < 1e-3
    # Two pegs: the oracle's K = 4 samples visit both, every sample is on a valid goal.
    assert report["coverage@4"] == 1.0 and report["precision@4"] == 1.0
    assert {r["num_modes"] for r in report["per_trial"]} == {2}
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == [
        "mug_medrack_seed0_gmm.png",
        "mug_medrack_seed0_samples.png",
        "mug_medrack_seed1_gmm.png",
        "mug_medrack_seed1_samples.png",
    ]
    assert all(p.read_bytes().startswith(PNG_SIGNATURE) for p in tmp_path.iterdir())
    path = write_json(tmp_path / "out" / "report.json", report)
    assert json.loads(path.read_text())["success"] == report["success"]


def test_errors_are_measured_as_the_error_that_was_made():
    trials = _trials("insert_waterproof", 3)
    shifted = evaluate(OraclePredictor(trials, translation=0.003), trials, 2, progress=False)
    assert shifted["success"]["success_rate"] < 1.0
    assert shifted["translation_error_mm"]["median"] == pytest.approx(3.0, abs=0.01)
    assert shifted["rotation_error_deg"]["median"] < 0.01
    # A pure translation moves the gripper by the same amount.
    assert shifted["gripper_translation_error_mm"]["median"] == pytest.approx(3.0, abs=0.01)
    assert shifted["executed_pose_translation_error_mm"]["median"] == pytest.approx(3.0, abs=0.01)
    assert shifted["executed_pose_rotation_error_deg"]["median"] < 0.01
    turned = evaluate(OraclePredictor(trials, rotation_deg=3.0), trials, 2, progress=False)
    assert turned["rotation_error_deg"]["median"] == pytest.approx(3.0, abs=0.01)
    assert turned["executed_pose_rotation_error_deg"]["median"] == pytest.approx(3.0, abs=0.01)
    assert turned["gripper_rotation_error_deg"]["median"] == pytest.approx(3.0, abs=0.01)
    assert "coverage@2" not in shifted  # one socket: no coverage to report


class StrayPoints(OraclePredictor):
    """The ground truth with a tenth of each cloud's points 10 cm off: the centroid moves, the rigid fit does not."""

    def sample_goals(self, object_points, scene_points, num_samples):
        samples = super().sample_goals(object_points, scene_points, num_samples)
        samples[:, :, : samples.shape[2] // 10] += torch.tensor([0.1, 0.0, 0.0], dtype=samples.dtype)
        return samples


def test_the_executed_pose_is_measured_apart_from_the_sampled_cloud():
    trials = _trials("insert_waterproof", 2)
    report = evaluate(StrayPoints(trials), trials, 2, progress=False)
    assert report["translation_error_mm"]["median"] == pytest.approx(10.0, abs=0.5)
    assert report["executed_pose_translation_error_mm"]["median"] < 0.01
    assert report["success"]["success_rate"] == 1.0  # what ran was the goal itself


class FirstSampleOff(OraclePredictor):
    """The ground truth, except that the first of the K samples is 3 cm off: a blind one-shot pick fails."""

    def sample_goals(self, object_points, scene_points, num_samples):
        samples = super().sample_goals(object_points, scene_points, num_samples)
        samples[:, 0] += torch.tensor([0.03, 0.0, 0.0], dtype=samples.dtype)
        return samples


def test_consensus_executes_the_sample_the_others_agree_with():
    trials = _trials("insert_waterproof", 2)
    first = evaluate(FirstSampleOff(trials), trials, 4, progress=False)
    assert first["success"]["success_rate"] == 0.0 and first["goal_selection"] == "first"
    assert first["translation_error_mm"]["median"] == pytest.approx(30.0, abs=0.01)
    voted = evaluate(FirstSampleOff(trials), trials, 4, goal_selection="consensus", progress=False)
    assert voted["success"]["success_rate"] == 1.0 and voted["goal_selection"] == "consensus"
    assert [r["executed_sample"] for r in voted["per_trial"]] == [1, 1]  # three agree; the earliest of them
    with pytest.raises(ValueError, match="goal selection: expected one of"):
        evaluate(FirstSampleOff(trials), trials, 4, goal_selection="best", progress=False)


def test_the_harness_rejects_what_is_not_a_goal_predictor():
    trials = _trials("insert_ssd", 1)

    class WrongShape:
        def sample_goals(self, object_points, scene_points, num_samples):
            return torch.zeros(1, num_samples, 7, 3)

    class NotFinite:
        def sample_goals(self, object_points, scene_points, num_samples):
            return torch.full((1, num_samples, *object_points.shape[1:]), float("nan"))

    with pytest.raises(
        ValueError, match=r"WrongShape.sample_goals returned shape \(1, 2, 7, 3\), expected \(1, 2, 512, 3\)"
    ):
        evaluate(WrongShape(), trials, 2, progress=False)
    with pytest.raises(ValueError, match="NaN"):
        evaluate(NotFinite(), trials, 2, progress=False)
    with pytest.raises(TypeError, match="neither sample_goals.* nor predict_poses"):
        evaluate(object(), trials, 2, progress=False)
    with pytest.raises(ValueError, match="object_points do not belong"):
        OraclePredictor(_trials("insert_ssd", 1, first_seed=5)).sample_goals(
            torch.from_numpy(trials[0].object_points)[None], torch.from_numpy(trials[0].scene_points)[None], 1
        )
    assert isinstance(OraclePredictor(trials), GoalPredictor)


class GroundTruthPoses:
    """A pose-only baseline: answers with each trial's T*, nothing else."""

    def __init__(self, trials):
        self._poses = [(t.object_points, t.goal_transform) for t in trials]

    def predict_poses(self, object_points, scene_points, num_samples):
        cloud = object_points[0].numpy()
        pose = next(p for o, p in self._poses if np.array_equal(o, cloud))
        return torch.from_numpy(np.asarray(pose, np.float32)).expand(1, num_samples, 4, 4)


def test_pose_only_predictors_are_executed_through_their_poses():
    trials = _trials("insert_waterproof", 2)
    report = evaluate(GroundTruthPoses(trials), trials, 2, progress=False)
    assert report["success"]["success_rate"] == 1.0
    assert report["translation_error_mm"]["median"] < 1e-2 and report["rotation_error_deg"]["median"] < 1e-2


def test_command_line_eval_writes_the_report(tmp_path):
    result = run_cli(
        "python",
        "-m",
        "lerobot_taxdpd.sim",
        "eval",
        "--task",
        "insert_dsub25",
        "--predictor",
        "oracle",
        "--trials",
        "2",
        "--num-samples",
        "2",
        "--goal-selection",
        "consensus",
        "--figures",
        "1",
        "--output",
        str(tmp_path),
    )
    assert "insert_dsub25: success 100.0%" in result.stdout
    report = json.loads((tmp_path / "insert_dsub25_eval.json").read_text())
    assert report["predictor"] == "oracle" and report["split"] == "test" and report["trials"] == 2
    assert report["goal_selection"] == "consensus"
    assert (tmp_path / "figures" / "insert_dsub25_seed0_samples.png").exists()


def test_true_placement_frames_measure_the_local_stage_of_a_shipped_predictor(tmp_path, capsys):
    """At the demonstrated goal's centroid the shipped connector's samples land where the true goal is; the
    report says which frames it was made with, and the option is refused where it cannot apply."""
    base = ["eval", "--task", "insert_waterproof", "--trials", "2", "--num-samples", "2", "--figures", "0"]
    output = tmp_path / "true_frames"
    assert main([*base, "--goal-policy.path", "insert_waterproof", "--placement-frames", "true", "--output",
                 str(output)]) == 0  # fmt: skip
    report = json.loads((output / "insert_waterproof_eval.json").read_text())
    assert report["placement_frames"] == "true"
    assert report["translation_error_mm"]["median"] < 2.0  # the connector's sockets are 0.6 mm wide
    assert main([*base, "--predictor", "oracle", "--placement-frames", "true", "--output", str(tmp_path)]) == 1
    assert "--placement-frames: only applies to a TAX-DPD goal predictor" in capsys.readouterr().err
    assert main(["eval", "--task", "cloth_hang", "--placement-frames", "true", "--output", str(tmp_path)]) == 1
    assert "--placement-frames: only applies to a rigid task" in capsys.readouterr().err


def test_a_denser_scene_is_observed_when_asked_and_the_benchmark_still_holds(tmp_path, capsys):
    """`--scene-cloud-size` renders every trial's scene at that many points (what a local stage crops from);
    the ground truth still succeeds on it, and the report says how dense the scenes were."""
    base = ["eval", "--task", "insert_waterproof", "--trials", "2", "--num-samples", "1", "--figures", "0"]
    assert main([*base, "--predictor", "oracle", "--scene-cloud-size", "2048", "--output", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "insert_waterproof_eval.json").read_text())
    assert report["scene_points"] == 2048 and report["success"]["success_rate"] == 1.0
    assert main(["eval", "--task", "cloth_hang", "--scene-cloud-size", "2048", "--output", str(tmp_path)]) == 1
    assert "--scene-cloud-size: only applies to a rigid task" in capsys.readouterr().err


class SamplingSettingsOf:
    """A user's own predictor around a shipped one (other sampling settings): it states its training clouds only
    through the policy's `config` it exposes."""

    def __init__(self, name: str, **settings):
        from lerobot_taxdpd import load_goal_predictor

        self.policy = load_goal_predictor(name)
        self.config, self.settings = self.policy.config, settings

    def sample_goals(self, object_points, scene_points, num_samples, **kwargs):
        return self.policy.sample_goals(object_points, scene_points, num_samples, **(kwargs | self.settings))


def multi_socket_with_twenty_steps() -> SamplingSettingsOf:
    return SamplingSettingsOf("insert_waterproof_multi", num_inference_steps=20)


def test_a_predictor_given_by_factory_sees_scenes_as_dense_as_it_was_trained_on(tmp_path):
    """`--predictor module:factory` is observed like `--goal-policy.path`: a wrapper of the shipped multi-socket
    connector (trained on 4096-point scenes, whose local stage crops them) is shown 4096-point scenes, not the
    task's 1024 (on which the same predictor placed none of 100); an explicit `--scene-cloud-size` still wins."""
    factory = "test_sim_harness:multi_socket_with_twenty_steps"
    base = ["eval", "--task", "insert_waterproof_multi", "--predictor", factory, "--trials", "2", "--num-samples", "2",
            "--figures", "0"]  # fmt: skip
    assert main([*base, "--output", str(tmp_path / "as_trained")]) == 0
    report = json.loads((tmp_path / "as_trained" / "insert_waterproof_multi_eval.json").read_text())
    assert report["scene_points"] == 4096 and report["translation_error_mm"]["median"] < 2.0
    assert main([*base, "--scene-cloud-size", "2048", "--output", str(tmp_path / "asked")]) == 0
    assert json.loads((tmp_path / "asked" / "insert_waterproof_multi_eval.json").read_text())["scene_points"] == 2048


def test_eval_draws_the_frames_the_way_it_is_asked_and_says_which(tmp_path, capsys):
    """`--goal-policy.gmm-frames modes` samples the shipped book predictor's frames at its mixture's peaks, and
    `--goal-policy.frame-temperature 1` starts its local stage with the published frame noise instead of at
    them (it ships at 0): other goals from the same scenes and draws, and the report says how they were drawn."""
    base = ["eval", "--task", "book_shelf", "--goal-policy.path", "book_shelf", "--trials", "2", "--num-samples", "2",
            "--figures", "0"]  # fmt: skip
    published = ["--goal-policy.frame-temperature", "1"]
    variants = {
        "published": ([*published, "--goal-policy.gmm-frames", "components"], "components", 1.0),
        "modes": ([*published, "--goal-policy.gmm-frames", "modes"], "modes", 1.0),
        "as shipped": ([], "components", 0.0),
    }
    errors = {}
    for name, (flags, frames, temperature) in variants.items():
        assert main([*base, *flags, "--output", str(tmp_path / name)]) == 0
        report = json.loads((tmp_path / name / "book_shelf_eval.json").read_text())
        assert (report["gmm_frames"], report["frame_temperature"]) == (frames, temperature)
        errors[name] = [t["translation_error_mm"] for t in report["per_trial"]]
    assert errors["published"] != errors["modes"] and errors["published"] != errors["as shipped"]
    assert main(["eval", "--task", "book_shelf", "--predictor", "oracle", "--goal-policy.gmm-frames", "modes"]) == 1
    assert "--goal-policy.gmm-frames: only applies to a TAX-DPD goal predictor" in capsys.readouterr().err
    assert main([*base, "--goal-policy.frame-temperature", "-1", "--output", str(tmp_path / "refused")]) == 1
    assert "--goal-policy.frame-temperature -1.0: frame_temperature: must be a finite" in capsys.readouterr().err
    assert not (tmp_path / "refused").exists()


def test_command_line_errors_name_the_argument(tmp_path, capsys):
    assert (
        main(
            ["eval", "--task", "insert_ssd", "--predictor", "no_colon_here", "--trials", "1", "--output", str(tmp_path)]
        )
        == 1
    )
    assert "--predictor" in capsys.readouterr().err
    assert (
        main(["eval", "--task", "insert_ssd", "--predictor", "oracle", "--trials", "0", "--output", str(tmp_path)]) == 1
    )
    assert "--trials" in capsys.readouterr().err
    missing = tmp_path / "no_checkpoint_here"
    base = ["eval", "--task", "insert_ssd", "--trials", "1", "--output", str(tmp_path)]
    assert main([*base, "--goal-policy.path", str(missing)]) == 1
    assert f"--goal-policy.path {missing}: not a loadable TAX-DPD checkpoint" in capsys.readouterr().err
    assert main([*base, "--policy.path", str(missing)]) == 1  # the old spelling, for a goal predictor
    err = capsys.readouterr().err
    assert "--policy.path for a goal predictor is deprecated, use --goal-policy.path" in err
    assert f"--goal-policy.path {missing}: not a loadable" in err
    assert main([*base, "--predictor", "oracle", "--ground-truth-goals"]) == 1
    assert "--ground-truth-goals: only applies to --task cloth_hang" in capsys.readouterr().err
    assert main(base) == 1
    assert "--goal-policy.path or --predictor: give exactly one" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["eval", "--task", "no_such_task", "--predictor", "oracle"])
    assert "invalid choice" in capsys.readouterr().err


def test_help_shows_every_tasks_options_and_hides_old_spellings(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["eval", "--help"])
    assert exit_info.value.code == 0
    shown = capsys.readouterr().out
    for option in ("--goal-policy.path", "--policy.path", "--ground-truth-goals", "--workers", "--predictor"):
        assert option in shown
    assert "cloth_hang only" in shown and "--plots" not in shown


def _without_timings(report: dict) -> dict:
    timing = {"seconds", "predict_seconds", "seconds_per_trial", "predict_seconds_per_trial", "wall_seconds"}
    kept = {key: value for key, value in report.items() if key not in timing | {"machine"}}
    kept["per_trial"] = [{k: v for k, v in trial.items() if k not in timing} for trial in report["per_trial"]]
    return kept


def test_the_same_eval_command_gives_the_same_numbers(tmp_path):
    """Fresh processes start torch's global generator from a random seed: every draw must come from the trial."""
    reports = []
    for run in range(2):
        output = tmp_path / str(run)
        run_cli(
            "python", "-m", "lerobot_taxdpd.sim", "eval", "--task", "insert_waterproof", "--goal-policy.path",
            "insert_waterproof", "--seed", "0", "--trials", "1", "--num-samples", "3", "--figures", "0",
            "--output", output,
        )
        reports.append(json.loads((output / "insert_waterproof_eval.json").read_text()))
    assert _without_timings(reports[0]) == _without_timings(reports[1])
