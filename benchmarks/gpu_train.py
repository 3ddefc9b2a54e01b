"""Train several tasks' goal predictors side by side on one GPU within a wall-clock budget, and say how fast.

One `lerobot-train` process per task (`--policy.type=taxdpd` from the CPU recipe `taxdpd_cpu`, at the size and
batch given here, then the task's own `training_flags`, so the insert tasks train in the robot's frame), on
datasets made beforehand with `python -m lerobot_taxdpd.sim generate`. Phases, all inside `--budget-s`:

1. launches: the kernel-launching ops and host syncs of one training step and one K = 10 call at this size
   (`launch_figures` of benchmarks/speed.py; counted on the CPU, the same on any machine and any batch);
2. warm-up: every task side by side for `--warmup-steps`, which measures steps/s side by side and start-up;
3. alone: the first task alone for `--alone-steps` (0 skips it);
4. main: every task side by side for the step count the warm-up's rate fits into what is left of the budget
   (so the learning-rate schedule ends where the run does), a checkpoint every `--save-every-s`; a run still
   going at the budget is stopped, and its last checkpoint stands.

Steps/s are 1 / (updt_s + data_s) of `lerobot-train`'s log lines (median, the first line left out: it holds
the first steps' warm-up); samples/s are that times the batch. Everything lands under `--output`:
`PHASE/TASK/train.log` and `PHASE/TASK/train/checkpoints/`, and `gpu_train.json` (machine line, launch
profile, figures of every run), rewritten after each phase, so a machine taken back mid-run leaves the
phases done and the main runs' checkpoints so far.

    python benchmarks/gpu_train.py --dataset mug_easyrack=data/mug_easyrack \\
        --dataset insert_waterproof=data/insert_waterproof --output results/gpu_train

A GPU machine without the project's environment (no network, no lerobot, Python 3.12): on this machine

    python benchmarks/gpu_train.py --prepare-bundle outputs/gpu_bundle \\
        --dataset mug_easyrack=data/mug_easyrack --dataset insert_waterproof=data/insert_waterproof

gathers what it lacks into one folder: the wheels of the exact versions this environment has
(`pip download --no-deps`, for `--bundle-python`), a `lerobot_policy_taxdpd` dist-info stub (LeRobot finds
plugins by distribution name; the package itself comes from the source tree), a tiny stand-in for PyAV
(LeRobot's video_utils imports `av` at import time; these datasets hold no video) and each dataset as a
`.tar.xz` with its task's training flags (the GPU side has no pybullet to read them from). Copy the source
tree and that folder over, then on the GPU machine

    python benchmarks/gpu_train.py --bundle outputs/gpu_bundle --output results/gpu_train

installs the wheels into the bundle (`pip install --no-index --no-deps --target`), unpacks the datasets, puts
both first on the path and runs as above. In bundle mode LeRobot is also told that transformers is absent
(the machine's transformers 5 does not import beside LeRobot's huggingface_hub < 0.36; TAX-DPD never uses
it). These workarounds live here, in the launcher of this script, and nowhere in the package.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import importlib.util
import json
import math
import os
import re
import runpy
import signal
import statistics
import subprocess
import sys
import tarfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Set for the `lerobot-train` processes of a bundle run: their launcher enters the bundle too.
BUNDLE_ENV = "TAXDPD_GPU_BUNDLE"
#: The first argument that makes this script the launcher of one `lerobot-train` (its other arguments).
LAUNCHER = "lerobot-train"
#: Distributions the GPU machine lacks (docs: /work/shared/notes/gpu-run.md), at this environment's versions.
BUNDLED = (
    "lerobot",
    "draccus",
    "mergedeep",
    "pyyaml-include",
    "toml",
    "termcolor",
    "datasets",
    "multiprocess",
    "dill",
    "fsspec",
    "pyserial",
    "deepdiff",
    "orderly-set",
    "gymnasium",
    "farama-notifications",
    "diffusers",
    "huggingface_hub",
)
AV_STAND_IN = '''"""Stand-in for PyAV, written by benchmarks/gpu_train.py: LeRobot imports `av` at import time and reads
`av.logging` (torchvision too); datasets without video never open one. Anything else is an ImportError, which
torchvision takes as "no PyAV"."""

import types

logging = types.SimpleNamespace(
    ERROR=16, WARNING=24, set_level=lambda level: None, restore_default_callback=lambda: None
)


def __getattr__(name):
    if name.startswith("__"):
        raise AttributeError(name)
    raise ImportError(f"av.{name}: PyAV is not installed (this is a stand-in)")
'''
LOG_LINE = re.compile(r"updt_s:([\d.]+) data_s:([\d.]+)")
STOP_GRACE_S = 30.0


@dataclass
class Run:
    """One `lerobot-train` process of a phase."""

    task: str
    folder: Path
    command: list[str]
    process: subprocess.Popen | None = None
    started: float = 0.0
    wall_s: float = 0.0
    stopped_at_budget: bool = False

    @property
    def log(self) -> Path:
        return self.folder / "train.log"

    @property
    def output_dir(self) -> Path:
        return self.folder / "train"


# ---------------------------------------------------------------------------------------------- bundle
def prepare_bundle(bundle: Path, datasets: dict[str, Path], python_version: str) -> None:
    """Wheels, dist-info stub, PyAV stand-in, datasets and their tasks' flags, for a machine without them."""
    from lerobot_taxdpd.sim.tasks import get_task

    wheels = bundle / "wheels"
    pins = [f"{name}=={importlib.metadata.version(name)}" for name in BUNDLED]
    subprocess.run(
        [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "--python-version",
         python_version, "--dest", str(wheels), *pins],
        check=True,
    )  # fmt: skip
    version = importlib.metadata.version("lerobot_policy_taxdpd")
    stub = bundle / "stub" / f"lerobot_policy_taxdpd-{version}.dist-info"
    stub.mkdir(parents=True, exist_ok=True)
    (stub / "METADATA").write_text(f"Metadata-Version: 2.1\nName: lerobot_policy_taxdpd\nVersion: {version}\n")
    (bundle / "av_stand_in" / "av").mkdir(parents=True, exist_ok=True)
    (bundle / "av_stand_in" / "av" / "__init__.py").write_text(AV_STAND_IN)
    manifest = {"python": python_version, "wheels": pins, "datasets": {}}
    (bundle / "data").mkdir(exist_ok=True)
    for task, root in datasets.items():
        archive = bundle / "data" / f"{task}.tar.xz"
        with tarfile.open(archive, "w:xz") as tar:
            tar.add(root, arcname=task)
        manifest["datasets"][task] = {"archive": archive.name, "training_flags": list(get_task(task).training_flags)}
    (bundle / "bundle.json").write_text(json.dumps(manifest, indent=2))
    size = sum(p.stat().st_size for p in bundle.rglob("*") if p.is_file()) / 2**20
    print(f"bundle {bundle}: {len(pins)} wheels, {len(datasets)} datasets, {size:.1f} MiB; on the GPU machine:")
    print(f"python benchmarks/gpu_train.py --bundle {bundle} --output results/gpu_train")


def install_bundle(bundle: Path) -> dict:
    """Install the bundle's wheels and unpack its datasets (once); returns its manifest."""
    manifest = json.loads((bundle / "bundle.json").read_text())
    site = bundle / "site"
    if not site.is_dir():
        wheels = sorted(str(p) for p in (bundle / "wheels").glob("*.whl"))
        subprocess.run(
            [sys.executable, "-m", "pip", "install", "--no-index", "--no-deps", "--target", str(site), *wheels],
            check=True,
        )
    for task, entry in manifest["datasets"].items():
        if not (bundle / "data" / task).is_dir():
            with tarfile.open(bundle / "data" / entry["archive"]) as tar:
                tar.extractall(bundle / "data", filter="data")
    return manifest


def enter_bundle(bundle: Path) -> None:
    """Put the bundle's packages, the source tree and the stubs on this process's path and its children's,
    then tell LeRobot that transformers is absent (the machine's 5.x breaks beside huggingface_hub 0.35)."""
    paths = [bundle / "site", ROOT, bundle / "stub"]
    if importlib.util.find_spec("av") is None:
        paths.append(bundle / "av_stand_in")
    entries = [str(p.resolve()) for p in paths]
    sys.path[:0] = entries
    os.environ["PYTHONPATH"] = os.pathsep.join([*entries, *filter(None, [os.environ.get("PYTHONPATH")])])
    os.environ[BUNDLE_ENV] = str(bundle.resolve())
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    import lerobot.utils.import_utils as lerobot_imports

    lerobot_imports._transformers_available = False


def launch_lerobot_train(argv: list[str]) -> None:
    """Run `lerobot-train argv` in this process, inside the bundle when the parent ran from one."""
    if os.environ.get(BUNDLE_ENV):
        enter_bundle(Path(os.environ[BUNDLE_ENV]))
    sys.argv = ["lerobot-train", *argv]
    runpy.run_module("lerobot.scripts.lerobot_train", run_name="__main__")


# ---------------------------------------------------------------------------------------------- runs
def model_fields(args: argparse.Namespace) -> dict:
    """TaxDPDConfig fields of the size trained."""
    return {
        "hidden_dim": args.hidden,
        "num_blocks": args.blocks,
        "num_heads": args.heads,
        "max_neighbors": args.neighbors,
        "num_object_points": args.object_points,
        "num_scene_points": args.scene_points,
        "use_amp": args.amp,
    }


def make_run(
    task: str, dataset: Path, folder: Path, flags: list[str], steps: int, log_freq: int, save_freq: int
) -> Run:
    """A run of `task` writing under `folder`, `flags` being the size, device, batch and the task's flags."""
    from lerobot_taxdpd.recipes import recipe_path

    command = [
        sys.executable,
        str(Path(__file__).resolve()),
        LAUNCHER,
        f"--config_path={recipe_path('taxdpd_cpu')}",
        f"--dataset.repo_id=local/{task}",
        f"--dataset.root={dataset.resolve()}",
        f"--output_dir={folder / 'train'}",
        f"--steps={steps}",
        f"--log_freq={log_freq}",
        f"--save_freq={save_freq}",
        *flags,
    ]
    return Run(task, folder, command)


def start(run: Run) -> None:
    """Start the run's process in its own session (its data workers stop with it), output to its log."""
    run.folder.mkdir(parents=True, exist_ok=True)
    with run.log.open("w") as log:
        run.process = subprocess.Popen(run.command, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    run.started = time.perf_counter()


def stop(run: Run) -> None:
    """SIGTERM to the run's process group, SIGKILL after a grace period."""
    os.killpg(run.process.pid, signal.SIGTERM)
    try:
        run.process.wait(STOP_GRACE_S)
    except subprocess.TimeoutExpired:
        os.killpg(run.process.pid, signal.SIGKILL)
        run.process.wait()


def run_side_by_side(runs: list[Run], deadline: float) -> None:
    """Start every run, wait for them, stop those still going at `deadline`."""
    for run in runs:
        start(run)
    try:
        while any(run.process.poll() is None for run in runs):
            if time.perf_counter() >= deadline:
                for run in runs:
                    if run.process.poll() is None:
                        run.stopped_at_budget = True
                        stop(run)
            time.sleep(0.5)
    finally:
        for run in runs:
            if run.process.poll() is None:
                stop(run)
            run.wall_s = time.perf_counter() - run.started


def log_rates(log: Path, batch_size: int) -> dict:
    """Steps/s and samples/s from the log's updt_s/data_s lines (medians; the first line left out if not alone)."""
    lines = [(float(u), float(d)) for u, d in LOG_LINE.findall(log.read_text(errors="replace"))]
    measured = lines[1:] if len(lines) > 1 else lines
    if not measured:
        return {"log_lines": 0}
    update_s = statistics.median(u for u, _ in measured)
    data_s = statistics.median(d for _, d in measured)
    steps_per_s = 1.0 / max(update_s + data_s, 1e-9)
    return {
        "log_lines": len(lines),
        "update_s": update_s,
        "data_s": data_s,
        "steps_per_s": steps_per_s,
        "samples_per_s": steps_per_s * batch_size,
    }


def summary(run: Run, steps: int, batch_size: int) -> dict:
    """What a finished run left: figures, its last checkpoint and the step it holds, how it ended."""
    last = run.output_dir / "checkpoints" / "last"
    state = last / "training_state" / "training_step.json"
    return {
        "task": run.task,
        "steps_requested": steps,
        "checkpoint_step": json.loads(state.read_text())["step"] if state.is_file() else None,
        "checkpoint": str(last.resolve() / "pretrained_model") if state.is_file() else None,
        "log": str(run.log),
        "returncode": run.process.returncode,
        "stopped_at_budget": run.stopped_at_budget,
        "wall_s": run.wall_s,
        **log_rates(run.log, batch_size),
        "command": ["lerobot-train", *run.command[3:]],
    }


def phase(
    name: str,
    tasks: dict[str, Path],
    flags: dict[str, list[str]],
    args,
    steps: int,
    log_freq: int,
    save_freq: int,
    deadline: float,
) -> dict:
    """Run `tasks` side by side for `steps` each; returns the phase's figures."""
    runs = [
        make_run(task, root, args.output / name / task, flags[task], steps, log_freq, save_freq)
        for task, root in tasks.items()
    ]
    together = "alone" if len(runs) == 1 else f"{len(runs)} runs side by side"
    print(f"[{name}] {together}, {steps} steps each, batch {args.batch}", flush=True)
    run_side_by_side(runs, deadline)
    results = [summary(run, steps, args.batch) for run in runs]
    for result in results:
        rate = (
            f"{result['steps_per_s']:.2f} steps/s, {result['samples_per_s']:.0f} samples/s"
            if "steps_per_s" in result
            else "no log line"
        )
        ending = "stopped at the budget" if result["stopped_at_budget"] else f"exit {result['returncode']}"
        print(
            f"[{name}]   {result['task']}: {rate}; checkpoint at step {result['checkpoint_step']} ({ending})",
            flush=True,
        )
    return {"side_by_side": len(runs) > 1, "runs": results}


def failed(results: dict) -> list[str]:
    """Runs that ended with an error of their own (not stopped at the budget)."""
    return [r["log"] for r in results["runs"] if r["returncode"] != 0 and not r["stopped_at_budget"]]


def startup_s(results: dict) -> float:
    """Seconds from start to the first step: a run's wall time less its steps at its measured rate."""
    return max(r["wall_s"] - r["steps_requested"] / r["steps_per_s"] for r in results["runs"])


# ---------------------------------------------------------------------------------------------- main
def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", action="append", default=[], metavar="TASK=DIR", help="a sim task's dataset")
    parser.add_argument("--output", type=Path, default=Path("results/gpu_train"), help="a folder not there yet")
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--budget-s", type=float, default=480.0, help="wall-clock budget of the whole command")
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--hidden", type=int, default=128)
    parser.add_argument("--blocks", type=int, default=5)
    parser.add_argument("--heads", type=int, default=4)
    parser.add_argument("--neighbors", type=int, default=64)
    parser.add_argument("--object-points", type=int, default=512)
    parser.add_argument("--scene-points", type=int, default=1024)
    parser.add_argument("--amp", action=argparse.BooleanOptionalAction, default=True, help="bf16 autocast")
    parser.add_argument("--num-workers", type=int, default=4, help="data workers of each run")
    parser.add_argument("--warmup-steps", type=int, default=60)
    parser.add_argument("--alone-steps", type=int, default=150, help="the first task alone (0: skip)")
    parser.add_argument("--max-steps", type=int, default=None, help="cap on the main runs' steps")
    parser.add_argument("--save-every-s", type=float, default=60.0, help="checkpoint interval of the main runs")
    parser.add_argument("--launch-batch", type=int, default=2, help="batch of the launch count (it does not change it)")
    parser.add_argument("--bundle", type=Path, default=None, help="run from a folder made by --prepare-bundle")
    parser.add_argument("--prepare-bundle", type=Path, default=None, metavar="DIR", help="make that folder and exit")
    parser.add_argument("--bundle-python", default="3.12", help="Python version of the bundle's wheels")
    parser.add_argument("extra", nargs="*", help="after --: more lerobot-train flags, last (they win)")
    args = parser.parse_args(argv)
    args.datasets = {}
    for pair in args.dataset:
        task, _, folder = pair.partition("=")
        if not (Path(folder) / "meta" / "info.json").is_file():
            parser.error(f"--dataset {pair}: expected TASK=DIR with DIR a LeRobot dataset (no meta/info.json)")
        args.datasets[task] = Path(folder)
    return args


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == [LAUNCHER]:
        launch_lerobot_train(argv[1:])
        return 0
    args = parse_args(argv)
    began = time.perf_counter()
    deadline = began + args.budget_s
    if args.prepare_bundle is not None:
        prepare_bundle(args.prepare_bundle, args.datasets, args.bundle_python)
        return 0
    task_flags = {}
    if args.bundle is not None:
        manifest = install_bundle(args.bundle)
        enter_bundle(args.bundle)
        for task, entry in manifest["datasets"].items():
            args.datasets.setdefault(task, args.bundle / "data" / task)
            task_flags[task] = entry["training_flags"]
    if not args.datasets:
        raise SystemExit("no dataset: give --dataset TASK=DIR (or a --bundle that holds some)")
    if args.output.exists():
        raise SystemExit(f"--output {args.output} exists: lerobot-train refuses to reuse its folders; choose another")
    return train(args, task_flags, deadline)


def train(args: argparse.Namespace, task_flags: dict[str, list[str]], deadline: float) -> int:
    """The launch count, then the warm-up, alone and main phases; writes the JSON after each."""
    import torch
    from speed import launch_figures

    from lerobot_taxdpd.reports.benchmarking import machine_info, write_json

    fields = model_fields(args)
    gpu = torch.cuda.get_device_name(0) if args.device.startswith("cuda") else "none (CPU run)"
    report = {"machine": machine_info(gpu=gpu), "arguments": vars(args), "model": fields, "phases": {}}
    machine = report["machine"]
    print(f"machine: {gpu} | torch {torch.__version__} | {machine['cpu']} ({machine['cpu_count']} cores)")
    report["launches"] = launch_figures(fields, args.launch_batch)
    for what, counted in report["launches"].items():
        print(f"launches, {what}: {counted['ops']} ops, {counted['syncs']} host syncs", flush=True)
    json_path = write_json(args.output / "gpu_train.json", report)
    flags = {task: run_flags(args, fields, task, task_flags) for task in args.datasets}

    def record(name: str, results: dict) -> bool:
        report["phases"][name] = results
        write_json(json_path, report)
        if failed(results):
            print(f"[{name}] failed; see {', '.join(failed(results))}", file=sys.stderr)
        return not failed(results)

    warm_freq = max(1, args.warmup_steps // 6)
    warmup = phase("warmup", args.datasets, flags, args, args.warmup_steps, warm_freq, args.warmup_steps, deadline)
    if not record("warmup", warmup) or any("steps_per_s" not in r for r in warmup["runs"]):
        return 1
    rate, startup = min(r["steps_per_s"] for r in warmup["runs"]), startup_s(warmup)
    if args.alone_steps:
        first = dict(list(args.datasets.items())[:1])
        freq = max(1, args.alone_steps // 6)
        if not record("alone", phase("alone", first, flags, args, args.alone_steps, freq, args.alone_steps, deadline)):
            return 1
    left = deadline - time.perf_counter() - startup
    if left * rate < 1:
        print(f"no budget left for the main runs (start-up {startup:.0f} s); wrote {json_path}", file=sys.stderr)
        return 1
    steps = max(1, math.floor(0.9 * rate * left))
    steps = min(steps, args.max_steps) if args.max_steps else steps
    log_freq, save_freq = max(1, round(10 * rate)), max(1, round(args.save_every_s * rate))
    main_phase = phase("main", args.datasets, flags, args, steps, min(log_freq, steps), save_freq, deadline)
    ok = record("main", main_phase)
    print(f"wrote {json_path}")
    return 0 if ok else 1


def run_flags(args: argparse.Namespace, fields: dict, task: str, task_flags: dict[str, list[str]]) -> list[str]:
    """lerobot-train flags of a task's run: size, device, batch, workers, the task's own flags, then `extra`."""
    if task not in task_flags:
        from lerobot_taxdpd.sim.tasks import get_task

        task_flags[task] = list(get_task(task).training_flags)
    return [
        *(f"--policy.{key}={json.dumps(value)}" for key, value in fields.items()),
        f"--policy.device={args.device}",
        f"--batch_size={args.batch}",
        f"--num_workers={args.num_workers}",
        *task_flags[task],
        *args.extra,
    ]


if __name__ == "__main__":
    raise SystemExit(main())
