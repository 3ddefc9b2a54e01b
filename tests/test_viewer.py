"""The rerun viewer, headless: recordings saved with --save hold what a user would look at, read back with
rerun's own dataframe API; a trial shows the numbers `sim eval` gives for the same seed."""

from __future__ import annotations

import numpy as np
import pytest
import rerun.dataframe as rrd

from lerobot_taxdpd import load_goal_predictor
from lerobot_taxdpd.data.schema import ACTION_KEY, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.sim.generate import generate_dataset
from lerobot_taxdpd.sim.harness import evaluate
from lerobot_taxdpd.sim.tasks import get_task
from lerobot_taxdpd.sim.trials import make_trial
from lerobot_taxdpd.viewer import main


def _entities(path) -> set[str]:
    return {column.entity_path for column in rrd.load_recording(path).schema().component_columns()}


def _positions(path, entity: str) -> np.ndarray:
    table = rrd.load_recording(path).view(index="log_tick", contents=entity).select().read_all()
    return np.asarray(table.column(f"{entity}:Points3D:positions").to_pylist()[0])


def test_a_dataset_episode_is_saved_frame_by_frame(tmp_path):
    root = generate_dataset(
        get_task("insert_ssd"),
        episodes=2,
        split="train",
        repo_id="local/ssd",
        root=tmp_path / "data",
        frames_per_episode=3,
        progress=False,
    )
    recording = tmp_path / "episode.rrd"
    assert main(["dataset", "--root", str(root), "--episode", "1", "--save", str(recording)]) == 0
    entities = _entities(recording)
    assert {f"/{OBJECT_KEY}", f"/{SCENE_KEY}", f"/{ACTION_KEY}", "/correspondence", "/task"} <= entities
    frames = rrd.load_recording(recording).view(index="frame_index", contents=f"/{OBJECT_KEY}").select().read_all()
    assert frames.column("frame_index").to_pylist() == [0, 1, 2]


def test_a_trial_shows_the_samples_valid_goals_and_gmm_that_sim_eval_scores(tmp_path):
    recording = tmp_path / "trial.rrd"
    argv = ["trial", "--task", "insert_waterproof", "--goal-policy.path", "insert_waterproof", "--seed", "3"]
    assert main([*argv, "--num-samples", "3", "--save", str(recording)]) == 0
    entities = _entities(recording)
    assert {"/samples/1", "/samples/2", "/samples/3", "/samples/1/label", "/scene", "/object/start"} <= entities
    assert {"/gmm/heaviest_means", "/object/after_executing_sample_1", "/summary"} <= entities
    assert any(entity.startswith("/valid_goals/") for entity in entities)
    trial = make_trial(get_task("insert_waterproof"), 3, "test")
    report = evaluate(load_goal_predictor("insert_waterproof"), [trial], 3, progress=False)
    summary = rrd.load_recording(recording).view(index="log_tick", contents="/summary").select_static().read_all()
    text = str(summary.column("/summary:TextDocument:text").to_pylist()[0])
    assert f"translation_error_mm: {report['per_trial'][0]['translation_error_mm']}" in text
    scene_colours = rrd.load_recording(recording).view(index="log_tick", contents="/scene").select().read_all()
    assert len(np.unique(np.asarray(scene_colours.column("/scene:Points3D:colors").to_pylist()[0]))) > 1, (
        "scene points are coloured by their GMM weight"
    )
    np.testing.assert_allclose(_positions(recording, "/object/start"), trial.object_points)


def test_without_a_display_or_save_path_it_says_what_to_do(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["dataset", "--root", str(tmp_path), "--episode", "0"]) == 1
    assert "pass --save PATH" in capsys.readouterr().err
    assert main(["dataset", "--root", str(tmp_path), "--save", str(tmp_path / "x.rrd")]) == 1
    assert "is not a LeRobot dataset folder (no meta/info.json)" in capsys.readouterr().err
    assert not (tmp_path / "x.rrd").exists(), "a failed view leaves no stub recording"
    with pytest.raises(SystemExit):
        main(["trial", "--task", "insert_waterproof"])  # the goal predictor is required
