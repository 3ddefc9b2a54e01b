"""Reading raw demo files with errors that name the file and the field.

Every converter reads through here, so a truncated archive, a missing key or a cloud with NaN stops with
`<file>: field '<key>': <what is wrong>` instead of a NumPy traceback. Pickle is refused unless a caller
asks for it: only RPDiff's files need it (they store dicts as 0-d object arrays), and unpickling can run
arbitrary code, so such files must come from a source the user trusts.
"""

from __future__ import annotations

import re
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lerobot_taxdpd.data.validation import PointCloudError, check_point_cloud


class DemoError(ValueError):
    """A demo that cannot be converted; the message names the file and the field."""


class LayoutError(DemoError):
    """`--raw-dir` does not hold the source's layout: there is no demo that --skip-invalid could pass over."""


def layout_error(raw_dir: Path, problem: str, holds_layout: Callable[[Path], bool]) -> LayoutError:
    """`problem`, plus where below `raw_dir` the layout is: a --raw-dir one level too high is the common slip."""
    found = _folders_below(raw_dir, holds_layout)
    hint = f"; it is further down, in {', '.join(map(str, found[:3]))}: point --raw-dir there" if found else ""
    return LayoutError(f"{raw_dir}: {problem}{hint}")


def _folders_below(raw_dir: Path, accept: Callable[[Path], bool], depth: int = 3) -> list[Path]:
    """The shallowest sub-folders of `raw_dir` (at most `depth` levels down) that `accept` takes."""
    level = [raw_dir]
    for _ in range(depth):
        level = [child for folder in level for child in sorted(folder.iterdir(), key=natural_key) if child.is_dir()]
        found = [folder for folder in level if accept(folder)]
        if found or not level:
            return found
    return []


def natural_key(path: Path | str) -> list:
    """Sort key that puts demo_2 before demo_10."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", str(path))]


def open_npz(path: Path, *, allow_pickle: bool = False) -> np.lib.npyio.NpzFile:
    """Open an .npz archive lazily (fields are read on access).

    The zip signature is checked first: given anything else, `np.load(allow_pickle=True)` would unpickle
    the whole file, which the .npz format never asks for.
    """
    try:
        with open(path, "rb") as handle:
            signature = handle.read(4)
    except OSError as exc:
        raise DemoError(f"{path}: cannot be read ({exc})") from exc
    if signature != b"PK\x03\x04":
        raise DemoError(f"{path}: not an .npz archive (no zip signature; empty, truncated or another format)")
    try:
        return np.load(path, allow_pickle=allow_pickle)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise DemoError(f"{path}: not a readable .npz file ({type(exc).__name__}: {exc})") from exc


def read_field(archive: np.lib.npyio.NpzFile | dict, source: str, field: str):
    """One member of an archive (or of a demo dict); a missing, truncated or pickled member raises `DemoError`."""
    names = archive.files if isinstance(archive, np.lib.npyio.NpzFile) else [str(k) for k in archive]
    if field not in names:
        raise DemoError(f"{source}: missing field '{field}' (found: {', '.join(sorted(names)) or 'none'})")
    try:
        return archive[field]
    except ValueError as exc:
        if "allow_pickle" in str(exc):
            raise DemoError(
                f"{source}: field '{field}' holds pickled Python objects, which this format does not use"
            ) from exc
        raise DemoError(f"{source}: field '{field}' cannot be read ({exc})") from exc
    except (OSError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        raise DemoError(f"{source}: field '{field}' cannot be read, the file looks truncated ({exc})") from exc


def unwrap_dict(value: np.ndarray | dict, source: str, field: str) -> dict:
    """The dict inside a 0-d object array (how RPDiff and DEDO store dict-valued fields)."""
    if isinstance(value, np.ndarray) and value.dtype == object and value.shape == ():
        value = value.item()
    if not isinstance(value, dict):
        raise DemoError(f"{source}: field '{field}' should hold a dict, got {type(value).__name__}")
    return value


def dict_entry(mapping: dict, source: str, field: str, key: str):
    """`mapping[key]` of a dict-valued field, with an error naming `field['key']`."""
    if key not in mapping:
        raise DemoError(f"{source}: field '{field}' has no entry '{key}' (found: {', '.join(map(str, mapping))})")
    return mapping[key]


def as_cloud(value, source: str, field: str, *, min_points: int) -> np.ndarray:
    """A finite float64 (N, 3) cloud with at least `min_points` points."""
    try:
        cloud = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise DemoError(f"{source}: field '{field}' is not an array ({exc})") from exc
    if cloud.dtype.kind in "iu":
        cloud = cloud.astype(np.float64)
    check_point_cloud(cloud, f"{source}: field '{field}'", min_points=min_points)
    return cloud.astype(np.float64, copy=False)


def as_finite(value, source: str, field: str, shape: tuple[int | None, ...]) -> np.ndarray:
    """A finite float64 array whose shape matches `shape` (None matches any size)."""
    array = np.asarray(value)
    if array.dtype.kind not in "fiu" or len(array.shape) != len(shape) or any(
        want is not None and got != want for got, want in zip(array.shape, shape, strict=True)
    ):
        expected = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise DemoError(
            f"{source}: field '{field}' should be a numeric array of shape {expected}, got {array.dtype} {array.shape}"
        )
    if not np.isfinite(array).all():
        bad = int((~np.isfinite(array)).sum())
        raise PointCloudError(f"{source}: field '{field}' contains {bad} NaN or infinite values")
    return array.astype(np.float64, copy=False)
