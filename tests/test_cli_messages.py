"""What a user reads when a command cannot do what was asked, or does it on the wrong thing: the cause and the
flag that fixes it, before any long work starts."""

from __future__ import annotations

import pytest
import torch

from lerobot_taxdpd import TaxDPDConfig, TaxDPDPolicy
from lerobot_taxdpd.sim.cli import main


@pytest.fixture
def mug_predictor(tmp_path):
    """A tiny TAX-DPD checkpoint whose card says it was trained for mug_easyrack."""
    torch.manual_seed(0)
    config = TaxDPDConfig.for_point_clouds(64, 128, hidden_dim=16, num_blocks=1, num_heads=2, device="cpu")
    policy = TaxDPDPolicy(config)
    policy.metrics = {"task": "mug_easyrack"}
    policy.save_pretrained(tmp_path / "mug")
    return tmp_path / "mug"


def _eval(task: str, predictor, output, *options: str) -> list[str]:
    argv = ["eval", "--task", task, "--goal-policy.path", str(predictor), "--trials", "1", "--num-samples", "1"]
    return [*argv, "--figures", "0", "--output", str(output), *options]


def test_a_predictor_evaluated_on_another_task_than_its_cards_says_so(mug_predictor, tmp_path, capsys):
    assert main(_eval("book_shelf", mug_predictor, tmp_path / "eval")) == 0
    assert "trained for mug_easyrack, not for --task book_shelf" in capsys.readouterr().err
    assert main(_eval("mug_easyrack", mug_predictor, tmp_path / "eval")) == 0
    assert "warning" not in capsys.readouterr().err


@pytest.mark.skipif(torch.cuda.is_available(), reason="the message is for machines without a GPU")
@pytest.mark.parametrize("task", ["book_shelf", "cloth_hang"])
def test_device_cuda_without_a_gpu_names_the_missing_gpu(mug_predictor, tmp_path, capsys, task):
    assert main(_eval(task, mug_predictor, tmp_path / "eval", "--device", "cuda")) == 1
    error = capsys.readouterr().err
    assert "torch sees no CUDA GPU" in error and "--device cpu" in error and "not a loadable" not in error


def test_generate_into_an_existing_root_names_overwrite(tmp_path, capsys):
    (tmp_path / "taken").mkdir()
    argv = ["generate", "--task", "book_shelf", "--episodes", "1", "--repo-id", "local/x", "--root"]
    assert main([*argv, str(tmp_path / "taken")]) == 1
    assert "add --overwrite to replace it" in capsys.readouterr().err
