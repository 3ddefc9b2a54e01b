"""The package as a regular install sees it: built into a wheel and used from outside the checkout.

The wheel's contents come first on PYTHONPATH and every command runs from an empty folder, so nothing can
fall back on the source tree (the editable install of the test environment included): what the wheel lacks
fails here.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from conftest import BIN, TINY_TAXDPD
from lerobot_taxdpd.apps.synthetic import write_slot_dataset

ROOT = Path(__file__).resolve().parents[1]
#: What pyproject.toml packages; copied so that building leaves no build/ or egg-info in the checkout.
SOURCES = ("pyproject.toml", "README.md", "lerobot_taxdpd", "lerobot_policy_taxdpd", "datasets_conv")


@pytest.fixture(scope="module")
def wheel_site(tmp_path_factory) -> Path:
    """The package built into a wheel (pip, offline, this environment's setuptools) and unpacked."""
    work = tmp_path_factory.mktemp("wheel")
    (work / "src").mkdir()
    for name in SOURCES:
        source = ROOT / name
        if source.is_dir():
            shutil.copytree(source, work / "src" / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(source, work / "src" / name)
    command = [
        sys.executable,
        "-m",
        "pip",
        "wheel",
        "-q",
        "--no-deps",
        "--no-build-isolation",
        "-w",
        work / "dist",
        work / "src",
    ]
    built = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert built.returncode == 0, built.stderr[-4000:]
    (wheel,) = (work / "dist").glob("lerobot_policy_taxdpd-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        archive.extractall(work / "site")
    return work / "site"


def run_installed(site: Path, cwd: Path, *command: str | Path) -> str:
    """Run a command with the wheel's contents first on the import path; its stdout."""
    env = {**os.environ, "PYTHONPATH": str(site)}
    result = subprocess.run(list(map(str, command)), capture_output=True, text=True, timeout=600, cwd=cwd, env=env)
    assert result.returncode == 0, f"{command} exited {result.returncode}\n{result.stderr[-6000:]}"
    return result.stdout


def test_the_wheel_finds_its_recipes_and_trains_on_one_with_lerobot_train(wheel_site, tmp_path):
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    python = sys.executable
    imported = run_installed(wheel_site, cwd, python, "-c", "import lerobot_taxdpd; print(lerobot_taxdpd.__file__)")
    assert Path(imported.strip()).is_relative_to(wheel_site)

    # taxdpd-demo --from-scratch and `sim pretrain` train with this recipe
    demo_recipe = run_installed(
        wheel_site,
        cwd,
        python,
        "-c",
        "from lerobot_taxdpd.recipes import recipe_path; from lerobot_taxdpd.sim.pretrain import CPU_RECIPE; "
        "print(recipe_path(CPU_RECIPE))",
    )
    assert Path(demo_recipe.strip()).is_relative_to(wheel_site) and Path(demo_recipe.strip()).is_file()
    listed = run_installed(wheel_site, cwd, python, "-m", "lerobot_taxdpd.recipes", "list")
    assert {"taxdpd_cpu", "taxdpd_ablation", "cloth_hang_gc_dp3"} <= {line.split()[0] for line in listed.splitlines()}
    recipe = Path(
        run_installed(wheel_site, cwd, python, "-m", "lerobot_taxdpd.recipes", "path", "taxdpd_ablation").strip()
    )
    assert recipe.is_relative_to(wheel_site)

    dataset = write_slot_dataset(tmp_path / "slots", episodes=4, object_cloud_size=32, scene_cloud_size=64)
    run_installed(
        wheel_site,
        cwd,
        BIN / "lerobot-train",
        f"--config_path={recipe}",
        "--policy.type=taxdpd",
        "--dataset.repo_id=local/slots",
        f"--dataset.root={dataset}",
        f"--output_dir={tmp_path / 'train'}",
        "--steps=2",
        "--batch_size=2",
        "--save_freq=2",
        "--num_workers=0",
        "--policy.num_object_points=32",
        "--policy.num_scene_points=64",
        *TINY_TAXDPD,
    )
    checkpoint = tmp_path / "train" / "checkpoints" / "last" / "pretrained_model"
    assert (checkpoint / "model.safetensors").is_file()
    assert not (cwd / "outputs").exists()  # the recipe's own output_dir was overridden, nothing left behind


def test_a_recipe_is_a_shipped_name_or_a_file(tmp_path, capsys):
    from lerobot_taxdpd.recipes import main, recipe_path

    own = tmp_path / "mine.json"
    own.write_text("{}")
    assert recipe_path(own) == own
    assert recipe_path("taxdpd_cpu").name == "taxdpd_cpu.json"
    assert main(["path", "no_such_recipe"]) == 1
    assert "no_such_recipe: neither a config file nor a shipped recipe (shipped: " in capsys.readouterr().err


def test_the_wheel_ships_every_checkpoint_file_of_the_checkout(wheel_site):
    """Goal predictors, their executors (`<name>/executor/`) and scorers (`<name>/scorer/`) load by name only if
    the wheel carries them."""
    shipped = ROOT / "lerobot_taxdpd" / "pretrained"
    in_checkout = {p.relative_to(shipped) for p in shipped.rglob("*") if p.is_file() and "__pycache__" not in p.parts}
    packaged = wheel_site / "lerobot_taxdpd" / "pretrained"
    assert in_checkout and {p.relative_to(packaged) for p in packaged.rglob("*") if p.is_file()} == in_checkout
