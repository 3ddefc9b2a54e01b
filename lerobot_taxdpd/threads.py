"""Torch's CPU thread count for this package's commands: one thread unless the user says otherwise.

Torch starts one OpenMP thread per core. On a small CPU that is doing anything else, those threads wait
for each other at every operation of these small point-cloud networks: measured on the 2-core target
machine with a training job beside it, `sample_goals` ran 3-75x slower with torch's default than with one
thread (`python benchmarks/threads.py`; README, "Threads"). One thread is never that trap, and costs at
most the parallel speed-up when the machine is idle. So every command of this package takes `--threads`;
without it, an `OMP_NUM_THREADS` or `MKL_NUM_THREADS` already set is respected, and otherwise it is 1.
The choice is exported as `OMP_NUM_THREADS`, so the worker processes and the `lerobot-train` runs a command
starts use it too.
"""

from __future__ import annotations

import argparse
import os

#: Variables torch reads its thread count from, in the order they are respected.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")
DEFAULT_THREADS = 1


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def add_threads_argument(parser: argparse.ArgumentParser) -> None:
    """The `--threads` option every command of the package shares."""
    parser.add_argument(
        "--threads",
        type=_positive,
        default=None,
        help=f"torch CPU threads (default: $OMP_NUM_THREADS or $MKL_NUM_THREADS if set, else {DEFAULT_THREADS}; "
        "more than one only pays on an otherwise idle machine, see the README's 'Threads')",
    )


def threads_from_environment() -> int | None:
    """The thread count the environment asks for, or None when it names none (or nonsense)."""
    for name in THREAD_VARIABLES:
        text = os.environ.get(name, "").strip()
        if text.isdigit() and int(text) > 0:
            return int(text)
    return None


def configure_threads(threads: int | None = None) -> int:
    """Set torch's thread count (see the module docstring for the default) and export it to child
    processes; returns the count."""
    import torch

    count = threads or threads_from_environment() or DEFAULT_THREADS
    torch.set_num_threads(count)
    os.environ["OMP_NUM_THREADS"] = str(count)
    return count
