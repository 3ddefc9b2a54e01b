"""Training recipes, and the one way this package starts `lerobot-train` and its own command lines.

A recipe is a `lerobot-train --config_path` file shipped inside the package (`lerobot_taxdpd/configs/*.json`),
so it is found on any install, editable or not:

    python -m lerobot_taxdpd.recipes list               # names, policy types and budgets
    python -m lerobot_taxdpd.recipes path taxdpd_cpu    # the file, for `lerobot-train --config_path=...`

Commands are recorded as a user types them (`lerobot-train ...`, `python -m ...`), in reports, metrics and
`train_command.txt`, and `run` executes them with this interpreter, so the package's own LeRobot is used
even where the environment's scripts are not on PATH.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from importlib import resources
from pathlib import Path

#: The shipped recipes: package data, a plain folder on every (non-zipped) install.
RECIPE_DIR = Path(str(resources.files("lerobot_taxdpd") / "configs"))

#: What a recorded command's first word runs as.
_PROGRAMS = {
    "lerobot-train": [sys.executable, "-m", "lerobot.scripts.lerobot_train"],
    "python": [sys.executable],
}


def list_recipes() -> dict[str, Path]:
    """Shipped recipe names -> their files."""
    return {path.stem: path for path in sorted(RECIPE_DIR.glob("*.json"))}


def recipe_path(name_or_path: str | Path) -> Path:
    """A shipped recipe name (`taxdpd_cpu`) or the path of a config file -> the config file."""
    path = Path(name_or_path).expanduser()
    if path.is_file():
        return path
    shipped = list_recipes()
    if str(name_or_path) in shipped:
        return shipped[str(name_or_path)]
    raise FileNotFoundError(
        f"{name_or_path}: neither a config file nor a shipped recipe (shipped: {', '.join(shipped) or 'none'})"
    )


def _policy_assignment(text: str) -> str:
    """One `--set` item, checked where it is parsed: `FIELD=VALUE`."""
    if "=" not in text or text.startswith("="):
        raise argparse.ArgumentTypeError(f"expected FIELD=VALUE, got {text}")
    return text


def add_policy_overrides_argument(parser: argparse.ArgumentParser, description: str) -> None:
    """The `--set FIELD=VALUE ...` option the benchmarks share: policy config fields over a recipe's."""
    parser.add_argument(
        "--set", nargs="*", default=[], type=_policy_assignment, metavar="FIELD=VALUE", help=description
    )


def policy_flags(assignments: Sequence[str]) -> list[str]:
    """`--set` items as `lerobot-train` flags (`--policy.FIELD=VALUE`)."""
    return [f"--policy.{assignment}" for assignment in assignments]


def train_command(
    dataset: Path, repo_id: str, output_dir: Path, *, recipe: Path | str | None = None, flags: Sequence[str] = ()
) -> list[str]:
    """`lerobot-train` on a dataset folder, from a recipe file or none, with `flags` (`--policy.<field>=...`,
    `--steps=...`, `--seed=...`) last so that they override the recipe."""
    command = ["lerobot-train"]
    if recipe is not None:
        command.append(f"--config_path={recipe}")
    command += [f"--dataset.repo_id={repo_id}", f"--dataset.root={dataset}", f"--output_dir={output_dir}"]
    return command + list(flags)


#: Policy fields a training run sets from its machine or its data, never from its recipe.
_RUN_SPECIFIC_FIELDS = {
    "type", "input_features", "output_features", "device", "push_to_hub", "repo_id", "private", "tags", "license",
    "pretrained_path", "point_scale", "cloud_center", "cloud_scale",
}  # fmt: skip


def _flags_beyond(recipe: dict, trained: dict) -> list[str]:
    """The `lerobot-train` flags that turn `recipe` into the run `trained` (both lerobot-train configs)."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.configs.train import TrainPipelineConfig

    policy = trained.get("policy", {})
    defaults = vars(PreTrainedConfig.get_choice_class(policy["type"])())
    set_by_recipe = recipe.get("policy", {})
    flags = []
    for field, value in policy.items():
        expected = set_by_recipe.get(field, defaults.get(field))
        if field not in _RUN_SPECIFIC_FIELDS and _as_json(value) != _as_json(expected):
            text = json.dumps(value, separators=(",", ":")) if isinstance(value, list | dict) else value
            flags.append(f"--policy.{field}={text}")  # one shell word
    run_defaults = {f.name: f.default for f in dataclasses.fields(TrainPipelineConfig)}
    for key in ("batch_size", "steps", "seed"):
        if key in trained and trained[key] != recipe.get(key, run_defaults.get(key)):
            flags.append(f"--{key}={trained[key]}")
    return flags


def _as_json(value):
    return json.loads(json.dumps(value, default=str))


def portable_train_command(trained: dict) -> str:
    """The `lerobot-train` command of a finished run, as anyone can type it: the shipped recipe it needs the
    fewest flags from (named by `python -m lerobot_taxdpd.recipes path`), those flags, and the run's dataset
    under `data/`, from its saved config (`train_config.json`), whatever folders it ran in."""
    policy_type = trained["policy"]["type"]
    repo_id = trained.get("dataset", {}).get("repo_id", "local/data")
    candidates = {}
    for name, path in list_recipes().items():
        recipe = json.loads(path.read_text())
        if recipe.get("policy", {}).get("type") == policy_type:
            candidates[name] = (recipe, _flags_beyond(recipe, trained))
    if not candidates:
        raise ValueError(f"no shipped recipe trains a {policy_type!r} policy")

    def fit(name: str) -> tuple[bool, int]:  # a recipe made for another dataset last, then the fewest flags
        recipe, flags = candidates[name]
        return recipe.get("dataset", {}).get("repo_id", repo_id) != repo_id, len(flags)

    name = min(candidates, key=fit)
    recipe, flags = candidates[name]
    recipe_dataset = recipe.get("dataset", {})
    root = recipe_dataset.get("root") if recipe_dataset.get("repo_id") == repo_id else None
    command = train_command(
        Path(root or f"data/{repo_id.split('/')[-1]}"),
        repo_id,
        Path("outputs/train") / name,
        recipe=f"$(python -m lerobot_taxdpd.recipes path {name})",
        flags=flags,
    )
    resumed = " (its last leg resumed an earlier checkpoint with --resume=true)" if trained.get("resume") else ""
    return " ".join(map(str, command)) + resumed


def run(
    command: Sequence[str], *, log: Path | None = None, threads: int | None = None, cwd: Path | None = None
) -> float:
    """Run a recorded command line (`lerobot-train ...` or `python ...`) with this interpreter; returns its
    wall time in seconds. `log` takes its output instead of the terminal; `threads` caps its OpenMP and MKL
    threads, for several runs side by side. Raises `CalledProcessError` when it fails."""
    if command[0] not in _PROGRAMS:
        raise ValueError(f"cannot run {command[0]!r}: expected one of {sorted(_PROGRAMS)}")
    argv = [*_PROGRAMS[command[0]], *map(str, command[1:])]
    env = None if threads is None else {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
    started = time.perf_counter()
    if log is None:
        subprocess.run(argv, check=True, env=env, cwd=cwd)
    else:
        log.parent.mkdir(parents=True, exist_ok=True)
        with log.open("w") as stream:
            subprocess.run(argv, stdout=stream, stderr=subprocess.STDOUT, check=True, env=env, cwd=cwd)
    return time.perf_counter() - started


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m lerobot_taxdpd.recipes", description=__doc__.split("\n\n")[0])
    verbs = parser.add_subparsers(dest="verb", required=True)
    verbs.add_parser("list", help="shipped recipes with their policy type and budget")
    path = verbs.add_parser("path", help="the file of a shipped recipe, for lerobot-train --config_path")
    path.add_argument("name")
    args = parser.parse_args(argv)
    if args.verb == "path":
        try:
            print(recipe_path(args.name))
        except FileNotFoundError as error:
            print(f"error: {error}", file=sys.stderr)
            return 1
        return 0
    for name, file in list_recipes().items():
        recipe = json.loads(file.read_text())
        print(
            f"{name:<20} --policy.type={recipe['policy']['type']:<8} "
            f"{recipe['steps']} steps, batch {recipe['batch_size']}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
