"""Goal predictors by name: shipped checkpoints, checkpoint folders and Hub ids (offline cache), and the
errors a user sees for anything else."""

from __future__ import annotations

import json
import re
import warnings

import pytest
import torch
from huggingface_hub import ModelCard
from lerobot.policies.factory import make_pre_post_processors

from conftest import install_in_hub_cache, run_cli
from lerobot_taxdpd import TaxDPDConfig, TaxDPDPolicy, goal_predictors, list_goal_predictors, load_goal_predictor
from lerobot_taxdpd.goal_predictors import SHIPPED_DIR, main, resolve_executor, resolve_goal_predictor


def _saved_policy(folder, metrics=None) -> TaxDPDPolicy:
    torch.manual_seed(0)
    config = TaxDPDConfig.for_point_clouds(
        16, 32, hidden_dim=16, num_blocks=1, num_heads=2, point_scale=20.0, device="cpu"
    )
    policy = TaxDPDPolicy(config)
    policy.metrics = metrics or {}
    policy.save_pretrained(folder)
    return policy


def test_a_checkpoint_folder_loads_and_a_folder_without_config_is_refused(tmp_path):
    policy = _saved_policy(tmp_path / "model", {"task": "slots"})
    loaded = load_goal_predictor(tmp_path / "model")
    assert not loaded.training and loaded.metrics == {"task": "slots"}
    for name, tensor in policy.state_dict().items():
        assert torch.equal(tensor, loaded.state_dict()[name]), name
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="no config.json"):
        load_goal_predictor(tmp_path / "empty")


def test_a_hub_id_resolves_through_the_offline_cache(tmp_path, hf_home):
    _saved_policy(tmp_path / "model", {"rmse_mm": 2.0})
    install_in_hub_cache(hf_home, "taxdpd-tests/by-name", tmp_path / "model")
    assert load_goal_predictor("taxdpd-tests/by-name").metrics == {"rmse_mm": 2.0}


def test_a_hub_id_missing_from_the_offline_cache_says_so_and_how_to_get_it():
    with pytest.raises(FileNotFoundError, match="HF_HUB_OFFLINE is set and it is not in the local") as error:
        load_goal_predictor("taxdpd-tests/never-downloaded")
    assert "Hugging Face cache" in str(error.value)
    assert "hf download taxdpd-tests/never-downloaded" in str(error.value)


def test_the_device_is_chosen_at_loading(tmp_path):
    _saved_policy(tmp_path / "model")
    policy = load_goal_predictor(tmp_path / "model", device="cpu")
    assert policy.config.device == "cpu" and next(policy.parameters()).device.type == "cpu"
    if torch.cuda.is_available():
        policy = load_goal_predictor(tmp_path / "model", device="cuda")
        assert policy.config.device == "cuda" and next(policy.parameters()).is_cuda
    else:
        with pytest.raises(ValueError, match="device: 'cuda' is not available on this machine"):
            load_goal_predictor(tmp_path / "model", device="cuda")


def test_unknown_names_list_the_shipped_ones():
    with pytest.raises(ValueError, match="unknown goal predictor 'no_such_task'.*shipped names") as error:
        resolve_goal_predictor("no_such_task")
    for name in list_goal_predictors():
        assert name in str(error.value)


def test_command_line_lists_names_and_resolves_paths(tmp_path, capsys):
    _saved_policy(tmp_path / "model")
    assert main(["path", str(tmp_path / "model")]) == 0
    assert capsys.readouterr().out.strip() == str(tmp_path / "model")
    assert main(["path", "no_such_task"]) == 1
    assert "unknown goal predictor" in capsys.readouterr().err
    listing = run_cli("python", "-m", "lerobot_taxdpd.goal_predictors", "list").stdout
    assert all(name in listing for name in list_goal_predictors())


def test_one_shipped_name_gives_the_goal_predictor_and_its_executor(tmp_path, monkeypatch, capsys):
    """A name whose folder holds executor/ resolves to it for --policy.path; a name without one is refused."""
    _saved_policy(tmp_path / "cloth_hang")
    _saved_policy(tmp_path / "mugs")
    (tmp_path / "cloth_hang" / "executor").mkdir()
    (tmp_path / "cloth_hang" / "executor" / "config.json").write_text("{}")
    monkeypatch.setattr(goal_predictors, "SHIPPED_DIR", tmp_path)
    assert resolve_goal_predictor("cloth_hang") == str(tmp_path / "cloth_hang")
    assert resolve_executor("cloth_hang") == str(tmp_path / "cloth_hang" / "executor")
    with pytest.raises(ValueError, match="unknown executor 'mugs'.*shipped names: cloth_hang$"):
        resolve_executor("mugs")
    assert main(["path", "cloth_hang", "--executor"]) == 0
    assert capsys.readouterr().out.strip() == str(tmp_path / "cloth_hang" / "executor")
    assert main(["list"]) == 0
    listing = capsys.readouterr().out.splitlines()
    assert [line.endswith("(+ gc_dp3 executor)") for line in listing] == [True, False]


def _portable(command: str) -> bool:
    """A card's training command runs on any machine: a shipped recipe by name, no folder of the training run;
    a second leg resumes the checkpoint that the first one writes, under its relative output folder."""
    first, *legs = command.split(" && ")
    output = re.search(r"--output_dir=(\S+)", first)
    resumed = f"--config_path={output and output.group(1)}/checkpoints/last/pretrained_model/train_config.json"
    return (
        first.startswith("lerobot-train --config_path=$(python -m lerobot_taxdpd.recipes path ")
        and "checkpoints/" not in first
        and all(re.fullmatch(rf"lerobot-train --resume=true --steps=\d+ {re.escape(resumed)}", leg) for leg in legs)
    )


@pytest.mark.parametrize("name", sorted(list_goal_predictors()))
def test_every_shipped_predictor_loads_by_name_and_states_its_measured_metrics(name):
    folder = SHIPPED_DIR / name
    assert (folder / "model.safetensors").stat().st_size < 8 * 2**20, "shipped checkpoints must stay small"
    assert (folder / "README.md").is_file() and (folder / "policy_preprocessor.json").is_file()
    metrics = json.loads((folder / "metrics.json").read_text())
    assert metrics["task"] == name and _portable(metrics["training_command"])
    assert 0.0 <= metrics["success"]["success_rate"] <= 1.0 and metrics["success"]["trials"] >= 100
    policy = load_goal_predictor(name)
    shapes = policy.config.input_features
    n_o, n_s = shapes["observation.pointcloud.object"].shape[0], shapes["observation.pointcloud.scene"].shape[0]
    generator = torch.Generator().manual_seed(0)
    size = policy.config.object_scale / policy.config.point_scale  # its training objects' radius
    obj, scene = torch.rand(1, n_o, 3) * size, torch.rand(1, n_s, 3) * 5 * size
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # inputs at the trained scale raise no unit warning
        goals = policy.sample_goals(obj, scene, 2, generator=generator)
    assert goals.shape == (1, 2, n_o, 3) and bool(torch.isfinite(goals).all())
    # its saved processors name their steps by registry name, which the package registers wherever it lives
    preprocessor, postprocessor = make_pre_post_processors(policy.config, pretrained_path=str(folder))
    assert "UnpackEnvironmentPointCloudsStep" in [type(step).__name__ for step in preprocessor.steps]
    assert type(postprocessor.steps[-1]).__name__ == "FlattenGoalCloudStep"


@pytest.mark.parametrize("name", sorted(list_goal_predictors()))
def test_every_shipped_card_names_its_task_reports_its_metrics_for_the_hub_and_runs(name):
    folder = SHIPPED_DIR / name
    metrics = json.loads((folder / "metrics.json").read_text())
    policy = load_goal_predictor(name)
    fresh = policy.generate_model_card(None, policy.name, policy.config.license, policy.config.tags)
    shipped = (folder / "README.md").read_text()
    assert shipped.strip() == str(fresh).strip(), (
        f"{folder}/README.md is stale: regenerate it from metrics.json with "
        "load_goal_predictor(name).generate_model_card(None, 'taxdpd', None, None).save(path)"
    )
    card = ModelCard.load(folder / "README.md")
    assert f"# TAX-DPD goal predictor for `{name}`" in card.text and "pip install lerobot_policy_taxdpd" in card.text
    assert "## Limitations" in card.text and f"{metrics['success']['success_rate']:.0%}" in card.text
    results = {result.metric_type: result.metric_value for result in card.data.eval_results}
    assert results["success_rate"] == pytest.approx(metrics["success"]["success_rate"])
    if "translation_error_mm" in metrics:
        assert results["translation_error_mm"] == pytest.approx(metrics["translation_error_mm"]["median"], abs=1e-4)
    assert {result.dataset_split for result in card.data.eval_results} == {"test"}
    if "equivariance_deg" in metrics:  # whether orientation is read off the scene, beside the trivial baselines
        turns = metrics["equivariance_deg"]
        assert f"turns the predicted goal by {turns['scene_yaw']:.1f} deg" in card.text
        if "baselines_true_position" in metrics:  # rigid tasks: success rates at the true position
            assert "Trivial baselines at the true position" in card.text
        if "copy_start_goal_metrics" in metrics:  # cloth: the copied start cloth's RMSEs
            assert "Trivial baseline, same scenes" in card.text
        assert {"baselines_true_position", "copy_start_goal_metrics"} & metrics.keys()
    example = card.text.split("```python\n", 1)[1].split("```", 1)[0]
    assert f'load_goal_predictor("{name}")' in example
    namespace: dict = {}
    exec(compile(example, f"{name}/README.md", "exec"), namespace)  # the card's example runs as written
    assert namespace["goals"].shape[:2] == (1, 10)


@pytest.mark.parametrize("name", sorted(goal_predictors.shipped_executors()))
def test_every_shipped_executor_loads_by_name_acts_and_states_its_success(name):
    """`--policy.path cloth_hang` works offline: weights, processors, a current card and measured success."""
    from lerobot_taxdpd.sim.cloth.evaluation import load_gc_dp3

    folder = SHIPPED_DIR / name / "executor"
    assert (folder / "model.safetensors").stat().st_size < 16 * 2**20, "shipped checkpoints must stay small"
    metrics = json.loads((folder / "metrics.json").read_text())
    assert metrics["task"] == name and _portable(metrics["training_command"])
    for key in ("success", "success_with_ground_truth_goals"):
        assert 0.0 <= metrics[key]["success_rate"] <= 1.0 and metrics[key]["trials"] >= 100
    saved = json.loads((folder / "config.json").read_text())
    assert saved["pretrained_path"] is None, "a shipped config must not point at the machine it was trained on"
    policy, preprocessor, postprocessor = load_gc_dp3(name)
    assert not policy.config.use_ema, "the shipped executor keeps only the EMA weights it acts with"
    fresh = policy.generate_model_card(None, policy.name, policy.config.license, policy.config.tags)
    assert (folder / "README.md").read_text().strip() == str(fresh).strip(), f"{folder}/README.md is stale"
    generator = torch.Generator().manual_seed(0)
    observation = {key: torch.rand(512, 3, generator=generator) for key in policy.config.cloud_keys}
    observation["observation.state"] = torch.zeros(12)
    with torch.inference_mode():
        action = postprocessor(policy.select_action(preprocessor(observation)))
    assert action.shape == (1, 6) and bool(torch.isfinite(action).all())
