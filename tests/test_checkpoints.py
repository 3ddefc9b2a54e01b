"""Broken checkpoints are refused with one error naming the file and what is wrong, whichever way they load.

Each damage is applied to a copy of a checkpoint laid out as `lerobot-train` writes one (config, safetensors
weights, processors), then loaded as a folder, as a shipped name and as a Hub id from the offline cache. A
checkpoint of the other policy type is refused, one from before later config fields loads with the values
those fields had, and nothing is ever unpickled. The same refusal through `lerobot-eval --policy.path` is in
the slow test at the end.
"""

from __future__ import annotations

import json
import pickle
import shutil
import subprocess
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file, save_file

from conftest import BIN, install_in_hub_cache
from lerobot_taxdpd import TaxDPDPolicy, goal_predictors, load_goal_predictor, make_taxdpd_pre_post_processors
from lerobot_taxdpd.policies.checkpoints import LEGACY_VALUES, CheckpointError, read_config
from lerobot_taxdpd.policies.gc_dp3.modeling_gc_dp3 import GcDp3Policy
from test_gc_dp3 import make_config as gc_dp3_config
from test_policy import clouds, tiny_policy

WEIGHTS, CONFIG = "model.safetensors", "config.json"


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """A tiny taxdpd checkpoint with its processors, as `lerobot-train` saves one."""
    folder = tmp_path_factory.mktemp("checkpoint") / "pretrained_model"
    policy = tiny_policy()
    policy.save_pretrained(folder)
    for processor in make_taxdpd_pre_post_processors(policy.config):
        processor.save_pretrained(folder)
    return folder


def _edit_weights(folder: Path, edit) -> None:
    weights = load_file(folder / WEIGHTS)
    edit(weights, sorted(name for name in weights if weights[name].ndim == 2)[0])
    save_file(weights, folder / WEIGHTS)


def _edit_config(folder: Path, **changes) -> None:
    config = json.loads((folder / CONFIG).read_text())
    config.update(changes)
    (folder / CONFIG).write_text(json.dumps(config))


def _truncate(folder: Path) -> None:
    data = (folder / WEIGHTS).read_bytes()
    (folder / WEIGHTS).write_bytes(data[: len(data) // 2])


def _rename_in_header(folder: Path) -> None:
    """An edit inside the JSON header: one tensor's name garbled, sizes and offsets intact."""
    data = bytearray((folder / WEIGHTS).read_bytes())
    start = data.index(b'"model.') + 1
    data[start : start + 5] = b"xxxxx"
    (folder / WEIGHTS).write_bytes(bytes(data))


#: damage -> (what it does to the checkpoint folder, the file and the words the error must hold).
DAMAGES = {
    "weights truncated": (_truncate, rf"{WEIGHTS}: not a readable safetensors file, truncated"),
    "weights emptied": (lambda f: (f / WEIGHTS).write_bytes(b""), rf"{WEIGHTS}: not a readable safetensors"),
    "weights missing": (lambda f: (f / WEIGHTS).unlink(), rf"{WEIGHTS}: missing"),
    "tensor renamed in the header": (_rename_in_header, rf"{WEIGHTS}: does not fit .*unexpected: xxxxx"),
    "tensor removed": (
        lambda f: _edit_weights(f, lambda w, name: w.pop(name)),
        rf"{WEIGHTS}: does not fit this taxdpd config \(missing: model\.",
    ),
    "tensor added": (
        lambda f: _edit_weights(f, lambda w, name: w.update(extra=torch.zeros(2))),
        rf"{WEIGHTS}: does not fit .*unexpected: extra",
    ),
    "tensor resized": (
        lambda f: _edit_weights(f, lambda w, name: w.update({name: torch.zeros(3, 3)})),
        rf"{WEIGHTS}: tensors of the wrong shape for config.json: .*\(3, 3\)",
    ),
    "NaN in the weights": (
        lambda f: _edit_weights(f, lambda w, name: w[name].fill_(float("nan"))),
        rf"{WEIGHTS}: NaN or infinite values in model\.",
    ),
    "config not JSON": (
        lambda f: (f / CONFIG).write_text('{"type": "taxdpd",'),
        rf"{CONFIG}: not a valid policy config",
    ),
    "config field unknown": (lambda f: _edit_config(f, wheels=4), rf"{CONFIG}: .*`wheels` are not valid"),
    "config field mistyped": (lambda f: _edit_config(f, hidden_dim="wide"), rf"{CONFIG}: .*`hidden_dim`"),
    "config value impossible": (
        lambda f: _edit_config(f, num_heads=3),
        rf"{CONFIG}: .*hidden_dim \(16\) must be divisible by num_heads \(3\)",
    ),
    "config type unknown": (lambda f: _edit_config(f, type="nope"), rf"{CONFIG}: .*'nope'"),
}


def _load(folder: Path, way: str, monkeypatch, hf_home: Path):
    """Load `folder` as a checkpoint folder, a shipped name, or a Hub id from the offline cache."""
    if way == "folder":
        return load_goal_predictor(folder)
    if way == "name":
        monkeypatch.setattr(goal_predictors, "SHIPPED_DIR", folder.parent)
        return load_goal_predictor(folder.name)
    repo_id = f"faults/{folder.parent.name}-{folder.name}"
    install_in_hub_cache(hf_home, repo_id, folder)
    return load_goal_predictor(repo_id)


def _damaged(checkpoint: Path, tmp_path: Path, name: str, damage) -> Path:
    folder = tmp_path / name.replace(" ", "_")
    shutil.copytree(checkpoint, folder)
    damage(folder)
    return folder


@pytest.mark.parametrize("way", ["folder", "name", "hub"])
@pytest.mark.parametrize("damage", sorted(DAMAGES))
def test_a_damaged_checkpoint_gives_one_error_naming_the_file(checkpoint, tmp_path, monkeypatch, hf_home, damage, way):
    edit, message = DAMAGES[damage]
    folder = _damaged(checkpoint, tmp_path, damage, edit)
    if way == "hub" and damage == "weights missing":
        message = "not in the local Hugging Face cache"  # offline, a file absent from the cache is a download
    with pytest.raises((CheckpointError, FileNotFoundError), match=message):
        _load(folder, way, monkeypatch, hf_home)


def test_a_checkpoint_of_the_other_policy_type_is_refused_both_ways(tmp_path):
    gc_dp3 = tmp_path / "gc_dp3"
    GcDp3Policy(gc_dp3_config()).save_pretrained(gc_dp3)
    with pytest.raises(CheckpointError, match=rf"gc_dp3/{CONFIG}: a 'gc_dp3' checkpoint, not a 'taxdpd' one"):
        load_goal_predictor(gc_dp3)
    taxdpd = tmp_path / "taxdpd"
    tiny_policy().save_pretrained(taxdpd)
    with pytest.raises(CheckpointError, match=rf"taxdpd/{CONFIG}: a 'taxdpd' checkpoint, not a 'gc_dp3' one"):
        GcDp3Policy.from_pretrained(taxdpd)


def test_a_checkpoint_without_processors_still_serves_the_python_api(checkpoint, tmp_path):
    """The API takes clouds in metres and needs no processor; lerobot-eval does (slow test below)."""
    folder = _damaged(checkpoint, tmp_path, "no_processor", lambda f: (f / "policy_preprocessor.json").unlink())
    goals = load_goal_predictor(folder).sample_goals(*clouds(1), 2)
    assert bool(torch.isfinite(goals).all())


def test_an_older_config_loads_with_the_values_its_missing_fields_had(checkpoint, tmp_path):
    """A config.json from before fields were added: they take the values of its time, not today's defaults;
    other missing fields take their defaults, and the weights load as saved."""
    older_fields = [*LEGACY_VALUES["taxdpd"], "use_ema", "ema_power", "start_yaw_range", "z_rotation_range"]

    def make_older(folder: Path) -> None:
        config = json.loads((folder / CONFIG).read_text())
        (folder / CONFIG).write_text(json.dumps({k: v for k, v in config.items() if k not in older_fields}))

    folder = _damaged(checkpoint, tmp_path, "older", make_older)
    policy = load_goal_predictor(folder)
    for name, value in LEGACY_VALUES["taxdpd"].items():
        assert getattr(policy.config, name) == value
    assert policy.config.use_ema is False
    saved, loaded = load_file(folder / WEIGHTS), policy.state_dict()
    assert saved.keys() == loaded.keys() and all(torch.equal(saved[k], loaded[k]) for k in saved)
    assert bool(torch.isfinite(policy.sample_goals(*clouds(1), 2)).all())


class _Marker:
    """Unpickling this writes the file named in its state: proof that something was unpickled."""

    def __init__(self, path: str) -> None:
        self.path = path

    def __reduce__(self):
        return (Path(self.path).write_text, ("unpickled",))


def test_nothing_is_ever_unpickled(checkpoint, tmp_path):
    """A checkpoint whose weights come only as torch pickles is refused for its missing safetensors file."""
    marker = tmp_path / "unpickled.txt"
    folder = _damaged(checkpoint, tmp_path, "pickles", lambda f: (f / WEIGHTS).unlink())
    for name in ("pytorch_model.bin", "model.pt", "model.pkl"):
        (folder / name).write_bytes(pickle.dumps(_Marker(str(marker))))
    with pytest.raises(CheckpointError, match=rf"{WEIGHTS}: missing"):
        load_goal_predictor(folder)
    assert not marker.exists()


@pytest.mark.slow
def test_lerobot_eval_refuses_a_damaged_checkpoint_naming_the_file(tmp_path):
    """Through LeRobot's own `lerobot-eval --policy.path`, on copies of the shipped mug_easyrack predictor."""
    shipped = Path(goal_predictors.resolve_goal_predictor("mug_easyrack"))
    for damage, expected in (
        ("tensor removed", f"{WEIGHTS}: does not fit"),
        ("weights truncated", f"{WEIGHTS}: not a readable safetensors file"),
        ("config value impossible", "num_heads (3)"),
        ("no processor", "policy_preprocessor.json"),
    ):
        edit = DAMAGES[damage][0] if damage in DAMAGES else lambda f: (f / "policy_preprocessor.json").unlink()
        folder = _damaged(shipped, tmp_path, damage, edit)
        command = [
            str(BIN / "lerobot-eval"),
            f"--policy.path={folder}",
            "--env.type=taxdpd_sim",
            "--env.task=mug_easyrack",
            "--eval.n_episodes=1",
            "--eval.batch_size=1",
            f"--output_dir={tmp_path / 'eval' / folder.name}",
        ]
        result = subprocess.run(command, capture_output=True, text=True, timeout=600)
        log = result.stdout + result.stderr
        print(f"{damage}: exit {result.returncode}; last line: {log.strip().splitlines()[-1]}")
        assert result.returncode != 0, f"lerobot-eval loaded a checkpoint with {damage}"
        assert expected in log, log[-3000:]


def test_a_checkpoint_without_a_weight_average_loads_into_a_policy_that_keeps_one(checkpoint):
    """Fine-tuning a shipped predictor (saved without its average) with `--policy.use_ema=true`: the average
    starts at the loaded weights rather than at a random initialisation."""
    config = read_config(checkpoint)
    config.use_ema = True
    policy = TaxDPDPolicy.from_pretrained(checkpoint, config=config)
    average, trained = policy.ema_model.state_dict(), policy.model.state_dict()
    assert average.keys() == trained.keys() and all(torch.equal(average[k], trained[k]) for k in trained)
