"""`sim pretrain` on a rerun: it reuses only what was made with the same options, says so, and refuses
the rest with the flag that replaces it, before any training starts."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from lerobot_taxdpd.goal_predictors import list_goal_predictors, resolve_goal_predictor
from lerobot_taxdpd.recipes import portable_train_command, recipe_path
from lerobot_taxdpd.sim.cli import main
from lerobot_taxdpd.sim.generate import generate_dataset
from lerobot_taxdpd.sim.pretrain import portable_commands, prepare_demonstrations, training_flags
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
