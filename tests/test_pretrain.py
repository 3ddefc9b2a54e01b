"""`sim pretrain` on a rerun: it reuses only what was made with the same options, says so, and refuses
the rest with the flag that replaces it, before any training starts."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from conftest import tiny_taxdpd_recipe
from lerobot_taxdpd.goal_predictors import list_goal_predictors, resolve_goal_predictor
from lerobot_taxdpd.recipes import portable_train_command, recipe_path
from lerobot_taxdpd.sim.cli import main
from lerobot_taxdpd.sim.generate import generate_dataset
from lerobot_taxdpd.sim.pretrain import portable_commands, prepare_demonstrations, trained_steps, training_flags
from lerobot_taxdpd.sim.tasks import get_task

TASK = "book_shelf"


@pytest.fixture
def output(tmp_path):
    """A pretrain work folder holding two demonstrations, as a first `--episodes 2` run leaves it."""
    generate_dataset(
        get_task(TASK), episodes=2, split="train", repo_id=f"local/{TASK}", root=tmp_path / "data", progress=False
    )
    return tmp_path


@pytest.mark.parametrize(
    ("options", "difference"),
    [
        (["--task", TASK, "--episodes", "3"], "scene seeds 0..1, not 0..2"),
        (["--task", "mug_easyrack"], "task book_shelf, not mug_easyrack"),
        (["--task", TASK, "--episodes", "2", "--scene-cloud-size", "2048"], "scene points default, not 2048"),
    ],
)
def test_a_rerun_with_other_options_refuses_the_old_demonstrations(output, capsys, options, difference):
    assert main(["pretrain", *options, "--output", str(output)]) == 1
    error = capsys.readouterr().err
    assert difference in error and "--overwrite" in error
    assert not (output / "train").exists()  # nothing trained on them
    assert json.loads((output / "data" / "meta" / "info.json").read_text())["total_episodes"] == 2


def test_matching_demonstrations_are_reused_and_overwrite_makes_new_ones(output, capsys):
    task = get_task(TASK)
    prepare_demonstrations(task, output / "data", f"local/{TASK}", 2, "cmd", overwrite=False)
    assert f"[1/4] reusing the 2 {TASK} demonstrations" in capsys.readouterr().out
    prepare_demonstrations(task, output / "data", f"local/{TASK}", 3, "cmd", overwrite=True)
    assert f"[1/4] 3 scripted {TASK} demonstrations" in capsys.readouterr().out
    assert json.loads((output / "data" / "meta" / "info.json").read_text())["total_episodes"] == 3


def test_a_predictor_trained_on_denser_scenes_is_evaluated_on_scenes_as_dense(tmp_path, capsys):
    """`--scene-cloud-size` records denser scenes than the task's default (the crop of a local stage is then
    finer); the recorded command makes them again, the held-out trials of a predictor trained on them are as
    dense, wherever it is evaluated, and a rerun without the flag does not reuse them silently."""
    from lerobot_taxdpd.goal_predictors import load_goal_predictor
    from lerobot_taxdpd.sim.predictors import observed_as_trained

    recipe = tiny_taxdpd_recipe(tmp_path / "tiny.json")
    output = tmp_path / "run"
    command = ["pretrain", "--task", TASK, "--config", str(recipe), "--steps", "2", "--episodes", "2", "--trials",
               "2", "--num-samples", "2", "--output", str(output), "--policy.local_scene_points=64"]  # fmt: skip
    assert main([*command, "--scene-cloud-size", "2048"]) == 0
    info = json.loads((output / "data" / "meta" / "info.json").read_text())
    assert info["features"]["observation.pointcloud.scene"]["shape"] == [2048, 3]
    metrics = json.loads((output / "metrics.json").read_text())
    assert metrics["data"].endswith("--scene-cloud-size 2048)")
    policy = load_goal_predictor(output / "train" / "checkpoints" / "last" / "pretrained_model")
    assert observed_as_trained(get_task(TASK), policy).num_points == (512, 2048)
    assert observed_as_trained(get_task(TASK), load_goal_predictor(TASK)) is get_task(TASK)  # shipped: as recorded
    capsys.readouterr()
    assert main(command) == 1
    assert "scene points 2048, not default" in capsys.readouterr().err


def test_recorded_commands_run_on_any_machine():
    """Metrics and cards name the folders of no machine: the data and run folders are relative, and a shipped
    recipe is found by name, so a reader can paste the commands after `pip install`."""
    listing = list_goal_predictors()
    texts = [f"{m.get('data', '')} {m.get('training_command', '')}" for m in listing.values()]
    texts += [path.read_text() for name in listing for path in [Path(resolve_goal_predictor(name)) / "README.md"]]
    assert texts and not [text for text in texts if re.search(r"[= (]/[a-z]", text)]
    task = get_task("insert_waterproof")
    generate, train = portable_commands(task, 5, recipe_path("taxdpd_cpu"), training_flags(task, 100, []))
    assert generate.endswith(
        "--episodes 5 --split train --repo-id local/insert_waterproof --root data/insert_waterproof"
    )
    assert train.startswith("lerobot-train --config_path=$(python -m lerobot_taxdpd.recipes path taxdpd_cpu) ")
    assert "--dataset.root=data/insert_waterproof" in train and "--policy.z_rotation_range=0" in train


@pytest.mark.parametrize(
    ("recipe", "repo_id", "changes", "flags"),
    [
        ("taxdpd_cpu", "local/mug_easyrack", {"frame_noise_std": 1.0}, ["--policy.frame_noise_std=1.0"]),
        ("cloth_hang_gc_dp3", "local/cloth_hang_policy", {"steps": 12000}, ["--steps=12000"]),
        ("cloth_hang_taxdpd", "local/cloth_hang_goal", {}, []),
    ],
)
def test_a_finished_runs_saved_config_gives_back_its_recipe_and_flags(recipe, repo_id, changes, flags):
    """What ship_pipeline records from a run's train_config.json: the recipe by name, then only what differs."""
    from lerobot.configs.policies import PreTrainedConfig

    trained = json.loads(recipe_path(recipe).read_text())
    policy_type = trained["policy"]["type"]
    defaults = {k: v for k, v in vars(PreTrainedConfig.get_choice_class(policy_type)()).items() if k != "type"}
    trained["policy"] = {**json.loads(json.dumps(defaults, default=str)), **trained["policy"]}
    trained["dataset"] = {"repo_id": repo_id, "root": "/home/someone/runs/data"}
    for key, value in changes.items():
        (trained if key == "steps" else trained["policy"])[key] = value
    command = portable_train_command(trained)
    assert command.startswith(f"lerobot-train --config_path=$(python -m lerobot_taxdpd.recipes path {recipe}) ")
    assert f"--dataset.repo_id={repo_id}" in command and "/home/someone" not in command
    assert [word for word in command.split() if word.startswith(("--policy.", "--steps", "--seed"))] == flags


def test_a_finished_run_trains_on_in_a_second_leg_and_ships_with_both_commands(tmp_path, capsys):
    """`--resume-steps` trains the run on from its last checkpoint (a long recipe in legs), records both legs'
    commands, and a later rerun must name the leg: a resumed run is never evaluated as the first leg alone."""
    from safetensors.torch import load_file

    recipe = tiny_taxdpd_recipe(tmp_path / "tiny.json")
    output = tmp_path / "run"
    first = ["pretrain", "--task", TASK, "--config", str(recipe), "--steps", "2", "--episodes", "2", "--trials", "2"]
    first += ["--num-samples", "2", "--output", str(output)]
    checkpoint = output / "train" / "checkpoints" / "last" / "pretrained_model"
    assert main([*first, "--resume-steps", "2"]) == 1  # refused before anything is made
    assert "--resume-steps 2: must be more than the first leg's 2 steps" in capsys.readouterr().err
    assert not output.exists()

    assert main(first) == 0
    first_leg = load_file(checkpoint / "model.safetensors")
    assert main([*first, "--resume-steps", "4"]) == 0
    out = capsys.readouterr().out
    assert "reusing the checkpoint" in out and "lerobot-train --resume=true --steps=4" in out
    assert trained_steps(checkpoint) == 4
    assert any((load_file(checkpoint / "model.safetensors")[k] != v).any() for k, v in first_leg.items())
    metrics = json.loads((output / "metrics.json").read_text())
    assert metrics["training_steps"] == 4
    train, leg = metrics["training_command"].split(" && ")
    assert "--steps=2" in train and leg == (
        f"lerobot-train --resume=true --steps=4 --config_path=outputs/train/{TASK}/checkpoints/last/pretrained_model/"
        "train_config.json"
    )

    assert main(first) == 1  # the run holds 4 steps now: evaluating it as the 2-step recipe would mislabel it
    error = capsys.readouterr().err
    assert "resumed to 4 steps" in error and "--resume-steps 4" in error
    assert main([*first, "--resume-steps", "4"]) == 0  # the same legs: reused, nothing trains
    assert "reusing the run resumed to 4 steps" in capsys.readouterr().out


def test_a_run_fine_tunes_from_a_shipped_predictor_and_records_where_it_started(tmp_path):
    """`--init-from NAME` starts from a shipped predictor's weights and architecture (at learning rate 0 the
    weights come out as they went in), and the new predictor's metrics say which weights it started from, how
    they were trained, and how to find them again on any install."""
    from safetensors.torch import load_file

    from lerobot_taxdpd.goal_predictors import weights_digest

    recipe = tiny_taxdpd_recipe(tmp_path / "tiny.json")
    output = tmp_path / "tuned"
    assert main(["pretrain", "--task", TASK, "--config", str(recipe), "--episodes", "2", "--trials", "2",
                 "--num-samples", "2", "--steps", "1", "--init-from", TASK, "--policy.optimizer_lr=0",
                 "--policy.use_ema=false", "--output", str(output)]) == 0  # fmt: skip
    shipped = Path(resolve_goal_predictor(TASK))
    before = load_file(shipped / "model.safetensors")
    after = load_file(output / "train" / "checkpoints" / "last" / "pretrained_model" / "model.safetensors")
    assert after.keys() == before.keys() and all((after[k] == before[k].float()).all() for k in after)
    metrics = json.loads((output / "metrics.json").read_text())
    origin = metrics["initialised_from"]
    assert origin["weights"] == weights_digest(shipped)
    assert origin["training_command"] == json.loads((shipped / "metrics.json").read_text())["training_command"]
    finds_it = f" --policy.path=$(python -m lerobot_taxdpd.goal_predictors path {TASK}) --policy.use_ema=false "
    assert finds_it in metrics["training_command"]  # unquoted, so that the shell runs it
