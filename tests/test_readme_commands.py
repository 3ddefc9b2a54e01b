"""Every fenced ```bash command of the README is accepted by the program it names, so a renamed flag, a removed
recipe or make target, a wrong module or script path, or a folder that no earlier command writes fails CI.

The rule, applied to each command in README order (continuation lines joined, `# ...` comments dropped, a
leading `VAR=value` set aside as environment):

- `$(...)` runs for real (the README uses it for `python -m lerobot_taxdpd.recipes path NAME` and
  `python -m lerobot_taxdpd.goal_predictors path NAME`, which print a path at once);
- `make TARGET`: `make -n TARGET` must succeed, so the target exists; nothing runs;
- `python -m MODULE ...`, `python SCRIPT ...` and this package's console scripts run in-process up to their
  argument parser, which must accept the arguments; the outermost `parse_args`/`parse_known_args` then stops
  the program, so nothing trains, converts or simulates. Arguments a program leaves to another (`sim pretrain`
  passes `--policy.*` on to `lerobot-train`) must be fields of the taxdpd policy config;
- `lerobot-train` / `lerobot-eval`: LeRobot's own parser (`lerobot.configs.parser.wrap`, what their `main`
  runs) builds the run's config from the command line and stops there. A `--config_path` inside the
  `--output_dir` of an earlier `lerobot-train` command (a resume) is that run's saved config, so it is parsed
  as that command's arguments followed by this one's;
- a path argument (`--config_path`, `--dataset.root`, `--raw-dir`, `--policy.path`, `--goal-policy.path`,
  `--collection`, `--scorer.path`) is a file of the checkout, a shipped predictor name, or at or below a folder
  an earlier command writes
  (its `--root`, `--output_dir`, `--output` or `--out`).

What this cannot see is a command that parses but fails when it runs. The converter block's commands run for
real in `test_convert_samples.py`, and the training block runs for real, shrunk by `shrink`, in the slow set;
the other programs run for real, on other command lines, in their own tests (`test_pretrain.py`,
`test_lerobot_train.py`, `test_sim_harness.py`, ...).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import io
import os
import re
import runpy
import shlex
import subprocess
import sys
import warnings
from collections.abc import Iterator
from importlib.metadata import entry_points
from pathlib import Path

import pytest
from draccus.wrappers import docstring
from lerobot.configs import parser as lerobot_parser
from lerobot.configs.eval import EvalPipelineConfig
from lerobot.configs.train import TrainPipelineConfig

from lerobot_taxdpd import TaxDPDConfig, list_goal_predictors
from lerobot_taxdpd.goal_predictors import shipped_executors

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
LEROBOT_CONFIGS = {"lerobot-train": TrainPipelineConfig, "lerobot-eval": EvalPipelineConfig}
INPUT_FLAGS = (
    "--config_path",
    "--dataset.root",
    "--raw-dir",
    "--policy.path",
    "--goal-policy.path",
    "--collection",
    "--scorer.path",
)
OUTPUT_FLAGS = ("--root", "--output_dir", "--output", "--out")


@dataclasses.dataclass(frozen=True)
class Command:
    """One command of a fenced block: where it starts in the file, and its text with continuations joined."""

    line: int
    text: str


def fenced_commands(path: Path, language: str = "bash") -> list[Command]:
    """The commands of every ```language block of a Markdown file, in order."""
    commands, inside, pending, start = [], False, "", 0
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if line.startswith("```"):
            inside = line == f"```{language}"
            continue
        if not inside or not (pending or line.strip()):
            continue
        start = start if pending else number
        pending += line.rstrip().removesuffix("\\") + " "
        if not line.rstrip().endswith("\\"):
            commands.append(Command(start, " ".join(pending.split())))
            pending = ""
    return commands


class Parsed(Exception):
    """Raised by the outermost argument parser once it has parsed: the program stops before doing anything."""

    def __init__(self, namespace: argparse.Namespace, extras: list[str]):
        super().__init__(namespace)
        self.extras = extras


@contextlib.contextmanager
def stop_after_parsing() -> Iterator[None]:
    """Make argparse raise `Parsed` when the outermost parse returns (subparsers parse inside it)."""
    known, full = argparse.ArgumentParser.parse_known_args, argparse.ArgumentParser.parse_args
    depth = 0

    def parse_known_args(self, args=None, namespace=None):
        nonlocal depth
        depth += 1
        try:
            namespace, extras = known(self, args, namespace)
        finally:
            depth -= 1
        if depth == 0:
            raise Parsed(namespace, extras)
        return namespace, extras

    def parse_args(self, args=None, namespace=None):
        nonlocal depth
        depth += 1
        try:
            namespace = full(self, args, namespace)  # exits on arguments it does not know, as for real
        finally:
            depth -= 1
        raise Parsed(namespace, [])

    argparse.ArgumentParser.parse_known_args, argparse.ArgumentParser.parse_args = parse_known_args, parse_args
    try:
        yield
    finally:
        argparse.ArgumentParser.parse_known_args, argparse.ArgumentParser.parse_args = known, full


def run_program(words: list[str]) -> None:
    """Run `python -m MODULE`, `python SCRIPT` or a console script of this environment in-process."""
    program, *args = words
    if program == "python" and args[:1] == ["-m"]:
        sys.argv = [args[1], *args[2:]]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # runpy: the module was imported before
            runpy.run_module(args[1], run_name="__main__", alter_sys=True)
    elif program == "python":
        sys.argv = [str(REPO / args[0]), *args[1:]]
        runpy.run_path(str(REPO / args[0]), run_name="__main__")
    else:
        scripts = entry_points(group="console_scripts", name=program)
        assert scripts, f"`{program}` is no console script of this environment"
        sys.argv = words
        next(iter(scripts)).load()()


def substitute(text: str) -> str:
    """`$(command)` replaced by what the command prints, run for real."""

    def output(match: re.Match) -> str:
        stdout = io.StringIO()
        with contextlib.redirect_stdout(stdout), pytest.raises(SystemExit) as stop:
            run_program(shlex.split(match.group(1)))
        assert stop.value.code in (0, None), f"$({match.group(1)}) exited {stop.value.code}"
        return stdout.getvalue().strip()

    return re.sub(r"\$\(([^()]*)\)", output, text)


def split_command(text: str) -> list[str]:
    """The program and its arguments, comments and leading `VAR=value` assignments dropped."""
    words = shlex.split(text, comments=True)
    while words and re.fullmatch(r"[A-Z_]+=\S*", words[0]):
        words = words[1:]
    return words


def flag_values(words: list[str], flags: tuple[str, ...]) -> list[tuple[str, str]]:
    """(flag, value) of each of `flags` given as `--flag=value` or `--flag value`."""
    found = []
    for i, word in enumerate(words):
        flag, equals, value = word.partition("=")
        if flag in flags:
            found.append((flag, value if equals else words[i + 1]))
    return found


def written_folders(commands: list[Command]) -> dict[str, Command]:
    """Each folder the commands write, with the command that writes it (read without running its `$(...)`,
    so that one broken substitution fails its own commands only)."""
    return {value: c for c in commands for _, value in flag_values(split_command(c.text), OUTPUT_FLAGS)}


def writer_of(path: str, folders: dict[str, Command]) -> Command | None:
    """The earlier command that writes `path` (at or below one of its output folders), if any."""
    for folder, command in folders.items():
        if Path(path) == Path(folder) or Path(folder) in Path(path).parents:
            return command
    return None


def check_paths(words: list[str], folders: dict[str, Command]) -> None:
    """Every input path names a file of the checkout, a shipped name, or what an earlier command writes."""
    shipped = {*list_goal_predictors(), *shipped_executors()}
    for flag, value in flag_values(words, INPUT_FLAGS):
        known = (REPO / value).exists() or value in shipped or writer_of(value, folders) is not None
        assert known, f"{flag} {value}: not in the checkout, not a shipped name, and no earlier command writes it"


def check_package_program(words: list[str]) -> None:
    """The program's own parser accepts the arguments; what it leaves over must be taxdpd policy fields."""
    with stop_after_parsing(), pytest.raises(Parsed) as parsed:
        run_program(words)
    fields = {field.name for field in dataclasses.fields(TaxDPDConfig)}
    for extra in parsed.value.extras:
        name = extra.removeprefix("--policy.").partition("=")[0]
        assert extra.startswith("--policy.") and name in fields, f"{extra}: not an argument of {shlex.join(words[:3])}"


def check_lerobot_program(words: list[str], folders: dict[str, Command]) -> None:
    """LeRobot's own parser builds the run's config from the arguments (a resume from the earlier run's)."""
    program, *args = words
    config_path = dict(flag_values(words, ("--config_path",))).get("--config_path", "")
    writer = writer_of(config_path, folders) if config_path else None
    earlier = split_command(substitute(writer.text)) if writer is not None else []
    if earlier[:1] == [program]:
        args = [*earlier[1:], *(arg for arg in args if not arg.startswith("--config_path"))]

    def probe(cfg):
        return cfg

    probe.__annotations__ = {"cfg": LEROBOT_CONFIGS[program]}
    sys.argv = [program, *args]
    assert isinstance(lerobot_parser.wrap()(probe)(), LEROBOT_CONFIGS[program])


def check_make_target(words: list[str]) -> None:
    """`make -n` names the commands of the target without running them; it fails on an unknown target."""
    result = subprocess.run(["make", "-n", *words[1:]], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, f"make -n {' '.join(words[1:])}: {result.stderr}"


COMMANDS = fenced_commands(README)


@pytest.fixture(scope="module", autouse=True)
def _docstrings_read_once():
    """draccus reads every config field's docstring from source for the help text of each parse (3 s a
    LeRobot command line); the text does not change between commands, so read it once."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(docstring, "get_attribute_docstring", functools.cache(docstring.get_attribute_docstring))
        yield


@pytest.mark.parametrize("index", range(len(COMMANDS)), ids=[f"README:{c.line}" for c in COMMANDS])
def test_every_readme_command_is_accepted_by_its_program(index, monkeypatch):
    monkeypatch.setattr(sys, "argv", list(sys.argv))  # the programs read sys.argv; it is restored after
    command = COMMANDS[index]
    folders = written_folders(COMMANDS[:index])
    words = split_command(substitute(command.text))
    check_paths(words, folders)
    if words[0] == "make":
        check_make_target(words)
    elif words[0] in LEROBOT_CONFIGS:
        check_lerobot_program(words, folders)
    else:
        check_package_program(words)


def test_the_readme_has_commands_of_every_kind_the_rule_covers():
    """Guards the guard: a fence renamed to ```sh or a changed block layout would otherwise test nothing."""
    programs = {split_command(c.text)[0] for c in COMMANDS}
    assert {"make", "python", "lerobot-train", "lerobot-eval", "taxdpd-convert"} <= programs


def shrink(text: str) -> str:
    """A command cut to seconds: `--episodes` 4, `--trials` 2 and `--steps` 2 (given to a `lerobot-train` that
    names none, which would run its recipe's budget), the rest as written."""
    if "--steps" not in text:
        text = text.replace("lerobot-train ", "lerobot-train --steps=2 ", 1)
    text = re.sub(r"(--episodes[ =])\d+", r"\g<1>4", text)
    return re.sub(r"(--(?:trials|steps)[ =])\d+", r"\g<1>2", text)


@pytest.mark.slow
def test_the_training_block_runs_for_real_shrunk(tmp_path):
    """The README's "Train a goal predictor" block, each command shrunk (see `shrink`), run by bash in order in an
    empty folder with this environment's programs first on PATH: demos, the CPU recipe, the fine-tune of its
    checkpoint and the paper-size line all finish."""
    heading = README.read_text().splitlines().index("### Train a goal predictor with LeRobot")
    block = [c for c in COMMANDS if heading < c.line][:4]
    assert [split_command(c.text)[0] for c in block] == ["python", "lerobot-train", "lerobot-train", "lerobot-train"]
    environment = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    for command in block:
        result = subprocess.run(
            ["bash", "-c", shrink(command.text)], cwd=tmp_path, env=environment, capture_output=True, text=True
        )
        assert result.returncode == 0, f"README:{command.line}: {shrink(command.text)}\n{result.stderr[-4000:]}"
