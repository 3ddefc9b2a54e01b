"""Checks the converter tests share. The raw demo files they convert come from `datasets_conv.samples`, the
writers behind `taxdpd-convert samples`, so a user tries the converters on exactly what the tests convert."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def row_indices(sampled, raw: np.ndarray) -> np.ndarray:
    """Index in `raw` of each row of `sampled` (exact float32 match); fails if a row is not in `raw`."""
    lookup = {row.tobytes(): i for i, row in enumerate(np.asarray(raw, dtype=np.float32))}
    rows = np.asarray(sampled, dtype=np.float32)
    missing = [i for i, row in enumerate(rows) if row.tobytes() not in lookup]
    assert not missing, f"{len(missing)} sampled rows are not rows of the raw cloud, e.g. {rows[missing[0]]}"
    return np.array([lookup[row.tobytes()] for row in rows])


def leftovers(root: Path) -> list[str]:
    """Hidden partial/previous folders the writer would leave beside `root` if it failed to clean up."""
    return sorted(p.name for p in root.parent.iterdir() if p.name.startswith(f".{root.name}."))
