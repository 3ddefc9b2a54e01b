"""`benchmarks/speed.py` on a CPU machine: its profile of a step prints no GPU error."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_stage_breakdown_prints_no_gpu_error_on_a_cpu_machine():
    script = (
        "import sys, torch; sys.path.insert(0, 'benchmarks'); import speed; "
        "print(speed.breakdown(lambda: torch.ones(8) @ torch.ones(8), 2))"
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "gpuGetDeviceCount" not in result.stderr + result.stdout
