"""`taxdpd` through LeRobot's own `lerobot-train`: train, fine-tune from a checkpoint, load for inference."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.factory import make_pre_post_processors

from conftest import TINY_TAXDPD as TINY
from lerobot_taxdpd import TaxDPDPolicy
from lerobot_taxdpd.apps.synthetic import make_slot_scene, write_slot_dataset
from lerobot_taxdpd.data.dataset_writer import DatasetCardInfo, DatasetWriter
from lerobot_taxdpd.data.schema import OBJECT_KEY, SCENE_KEY


@pytest.fixture(scope="module")
def slot_dataset(tmp_path_factory):
    return write_slot_dataset(
        tmp_path_factory.mktemp("data") / "slots", episodes=8, object_cloud_size=32, scene_cloud_size=64
    )


def train(cli, dataset, output_dir, *args, steps=4):
    return cli(
        "lerobot-train",
        "--dataset.repo_id=local/taxdpd_slots",
        f"--dataset.root={dataset}",
        "--policy.push_to_hub=false",
        "--batch_size=4",
        f"--steps={steps}",
        f"--save_freq={steps}",
        "--log_freq=1",
        "--num_workers=0",
        f"--output_dir={output_dir}",
        *args,
    )


def test_train_fine_tune_and_load_through_lerobot(cli, slot_dataset, tmp_path):
    result = train(cli, slot_dataset, tmp_path / "run", "--policy.type=taxdpd", *TINY)
    assert "loss:" in result.stdout + result.stderr
    checkpoint = tmp_path / "run" / "checkpoints" / "last" / "pretrained_model"
    saved = json.loads((checkpoint / "config.json").read_text())
    assert saved["type"] == "taxdpd" and saved["point_scale"] > 0  # dataset scaling lives in the checkpoint
    assert (checkpoint / "README.md").exists() and (checkpoint / "policy_preprocessor.json").exists()

    # Fine-tuning goes through lerobot's override path (device/rename/normalizer steps by registry name).
    train(cli, slot_dataset, tmp_path / "finetune", f"--policy.path={checkpoint}", steps=2)
    tuned = tmp_path / "finetune" / "checkpoints" / "last" / "pretrained_model"
    before, after = TaxDPDPolicy.from_pretrained(checkpoint), TaxDPDPolicy.from_pretrained(tuned)
    assert after.config.point_scale == before.config.point_scale
    assert any(not torch.equal(a, b) for a, b in zip(before.parameters(), after.parameters(), strict=True))

    # Inference the way lerobot-eval builds it: config + processors from the checkpoint, one unbatched sample.
    config = PreTrainedConfig.from_pretrained(tuned)
    preprocessor, postprocessor = make_pre_post_processors(
        config, pretrained_path=str(tuned), preprocessor_overrides={"device_processor": {"device": "cpu"}}
    )
    scene = make_slot_scene(np.random.default_rng(0), 32, 64)
    observation = preprocessor(
        {OBJECT_KEY: torch.from_numpy(scene.object_points), SCENE_KEY: torch.from_numpy(scene.scene_points)}
    )
    action = postprocessor(after.select_action(observation))
    assert action.shape == (1, 32 * 3) and bool(torch.isfinite(action).all())


def test_unknown_dataset_layout_fails_with_the_missing_feature_named(cli, tmp_path):
    features = {
        "observation.state": {"dtype": "float32", "shape": (3,), "names": None},
        "action": {"dtype": "float32", "shape": (3,), "names": None},
    }
    card = DatasetCardInfo(source="test", source_license="apache-2.0")
    with DatasetWriter("local/wrong", tmp_path / "wrong", features, fps=10, card=card) as writer:
        frame = {"observation.state": np.zeros(3, np.float32), "action": np.zeros(3, np.float32)}
        writer.add_episode([frame, frame], "nothing")
    with pytest.raises(pytest.fail.Exception, match="observation.pointcloud.object"):
        cli(
            "lerobot-train",
            "--policy.type=taxdpd",
            "--dataset.repo_id=local/wrong",
            f"--dataset.root={tmp_path / 'wrong'}",
            "--policy.push_to_hub=false",
            "--steps=1",
            "--num_workers=0",
            f"--output_dir={tmp_path / 'out'}",
            *TINY,
        )
