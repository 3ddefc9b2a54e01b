"""Test-wide set-up: no network, and a private Hugging Face cache per test session.

The environment is set at import time, before LeRobot reads HF_LEROBOT_HOME into module constants, and
is inherited by the CLI subprocesses the tests start (`lerobot-train`, converters, benchmarks).
"""

from __future__ import annotations

import atexit
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

_HF_HOME = Path(tempfile.mkdtemp(prefix="taxdpd-tests-hf-"))
# Removed when this process ends, whatever ends it short of a kill (every process that imports this file, the
# pytest controller and each worker, makes its own; a usage error ends pytest before its own hooks run).
atexit.register(shutil.rmtree, _HF_HOME, ignore_errors=True)
os.environ["HF_HOME"] = str(_HF_HOME)
os.environ["HF_LEROBOT_HOME"] = str(_HF_HOME / "lerobot")
os.environ["HF_HUB_OFFLINE"] = "1"
os.environ["WANDB_MODE"] = "disabled"
os.environ.setdefault("MPLBACKEND", "Agg")
if os.environ.get("PYTEST_XDIST_WORKER"):
    # Parallel workers (`make test` runs two) take one torch thread each, and so do the processes they start:
    # two jobs of two threads each on a two-core machine run about ten times slower than one of one.
    os.environ["OMP_NUM_THREADS"] = os.environ["MKL_NUM_THREADS"] = "1"

BIN = Path(sys.executable).parent

#: `lerobot-train` flags for a taxdpd model small enough to train a few steps in seconds.
TINY_TAXDPD = [
    "--policy.hidden_dim=16",
    "--policy.num_blocks=1",
    "--policy.num_heads=2",
    "--policy.max_neighbors=16",
    "--policy.num_inference_steps=2",
    "--policy.device=cpu",
]
#: The same for gc_dp3.
TINY_GC_DP3 = [
    "--policy.type=gc_dp3",
    "--policy.down_dims=[32,64]",
    "--policy.point_encoder_dims=[32,32]",
    "--policy.point_feature_dim=32",
    "--policy.state_encoder_dims=[32,32]",
    "--policy.diffusion_step_embed_dim=32",
    "--policy.scheduler_warmup_steps=20",
    "--policy.optimizer_lr=1e-3",
    "--policy.device=cpu",
]


def tiny_taxdpd_recipe(path: Path) -> Path:
    """The ablation recipe shrunk to seconds: the same file layout, a model a few kB large."""
    from lerobot_taxdpd.recipes import recipe_path  # not at import: the environment above is set first

    config = json.loads(recipe_path("taxdpd_ablation").read_text())
    for flag in TINY_TAXDPD:
        field, value = flag.removeprefix("--policy.").split("=")
        config["policy"][field] = value if field == "device" else int(value)
    config["policy"].update(num_object_points=32, num_scene_points=64)
    path.write_text(json.dumps(config))
    return path


def run_cli(name: str, *args: str, timeout: float = 600, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Run a console script of this environment (e.g. `lerobot-train`) and fail with its output on error."""
    command = [str(BIN / name), *map(str, args)]
    result = subprocess.run(command, capture_output=True, text=True, timeout=timeout, cwd=cwd)
    if result.returncode != 0:
        pytest.fail(
            f"{' '.join(command)} exited {result.returncode}\n--- stdout\n{result.stdout[-4000:]}"
            f"\n--- stderr\n{result.stderr[-8000:]}"
        )
    return result


def install_in_hub_cache(hf_home: Path, repo_id: str, files: Path, revision: str = "0" * 40) -> None:
    """Lay files out exactly as huggingface_hub caches a downloaded model repo."""
    repo_dir = hf_home / "hub" / f"models--{repo_id.replace('/', '--')}"
    shutil.copytree(files, repo_dir / "snapshots" / revision)
    (repo_dir / "refs").mkdir()
    (repo_dir / "refs" / "main").write_text(revision)


@pytest.fixture
def hf_home() -> Path:
    """The session's private, offline Hugging Face home."""
    return _HF_HOME


@pytest.fixture
def cli():
    """`run_cli` as a fixture (a dependency installs its own top-level `tests` package, so don't import it)."""
    return run_cli


def pytest_collection_modifyitems(config, items) -> None:
    """Tests marked `long` (minutes each) start first, so that parallel workers share the rest while they run."""
    items.sort(key=lambda item: item.get_closest_marker("long") is None)
