"""What every benchmark and evaluation report records beside its figures: the machine, the thread count and
the library versions, medians of repeats, and the JSON file itself (written atomically)."""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


#: Libraries whose version a report names when the run has loaded them (name -> how to read it).
_OPTIONAL_LIBRARIES = {
    "pybullet": ("pybullet_api", lambda module: module.getAPIVersion()),
    "open3d": ("open3d", lambda module: module.__version__),
    "fpsample": ("fpsample", lambda module: getattr(module, "__version__", "unknown")),
}


def machine_info(**versions: object) -> dict:
    """Machine, load and library versions: numpy and torch, the optional libraries this process has loaded
    (pybullet for a simulation report, open3d and fpsample for a converter's), and any `versions` given."""
    import numpy as np
    import torch

    loaded = {
        key: read(sys.modules[name]) for name, (key, read) in _OPTIONAL_LIBRARIES.items() if name in sys.modules
    }
    return {
        "platform": platform.platform(),
        "cpu": cpu_model(),
        "cpu_count": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0],  # other work on the machine slows every figure
        "torch_threads": torch.get_num_threads(),
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "torch": torch.__version__,
        **loaded,
        **versions,
    }


def timed(run: Callable[[], object], repeats: int, warmup: int = 1) -> tuple[float, list[float]]:
    """Median and all wall times (seconds) of `repeats` calls after `warmup` untimed ones."""
    for _ in range(warmup):
        run()
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        run()
        times.append(time.perf_counter() - started)
    return statistics.median(times), times


def _path_as_text(value):
    """JSON for the paths that argparse namespaces carry; anything else unknown is still an error."""
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"Object of type {type(value).__name__} is not JSON serializable")


def write_json(path: str | Path, payload: dict) -> Path:
    """Write `payload` as indented JSON (paths as text); a crash never leaves a half-written file behind."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial")
    partial.write_text(json.dumps(payload, indent=2, default=_path_as_text))
    os.replace(partial, path)
    return path
