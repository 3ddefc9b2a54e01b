"""The part every converter shares: options, point sampling, the write loop and the end-of-run summary.

A source module only lists its demos (`DemoRef`) and turns one of them into the frames of one episode; this
module feeds them through the atomic `DatasetWriter` with a progress bar, skips bad demos when asked, and
reports what happened.
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from datasets_conv.raw_io import DemoError
from lerobot_taxdpd.data.dataset_writer import DatasetCardInfo, DatasetWriter, SkippedItem
from lerobot_taxdpd.data.schema import placement_frame
from lerobot_taxdpd.data.validation import PointCloudError
from lerobot_taxdpd.maths.geometry import farthest_point_indices, transform_points

SPLITS = ("train", "val", "test", "all")


@dataclass(frozen=True)
class DemoRef:
    """One demo of a raw dataset: `source` is what errors and the summary call it."""

    source: str
    path: Path
    key: str | None = None


@dataclass
class ConversionOptions:
    """Choices shared by every source; `None` cloud sizes (points stored per frame) mean the task's default
    from the paper."""

    object_cloud_size: int | None = None
    scene_cloud_size: int | None = None
    frames_per_episode: int = 2
    split: str = "all"
    seed: int = 0
    skip_invalid: bool = False
    overwrite: bool = False
    hub_license: str | None = None
    task: str | None = None
    command: str | None = None

    def __post_init__(self) -> None:
        if self.split not in SPLITS:
            raise ValueError(f"split: expected one of {SPLITS}, got {self.split!r}")
        if self.frames_per_episode < 2:
            raise ValueError(
                f"frames_per_episode: LeRobot 0.4.4 needs at least 2 frames per episode, got {self.frames_per_episode}"
            )
        for name in ("object_cloud_size", "scene_cloud_size"):
            value = getattr(self, name)
            if value is not None and value < 3:
                raise ValueError(f"{name}: need at least 3 points, got {value}")

    def point_counts(self, default: tuple[int, int]) -> tuple[int, int]:
        return (self.object_cloud_size or default[0], self.scene_cloud_size or default[1])


@dataclass
class ConversionSummary:
    """What a run did, printed at the end and returned to Python callers."""

    source: str
    repo_id: str
    output: Path
    demos_read: int
    episodes: int
    frames: int
    skipped: list[SkippedItem]
    seconds: float
    notes: list[str] = field(default_factory=list)

    def __str__(self) -> str:
        rate = self.demos_read / self.seconds if self.seconds > 0 else float("nan")
        lines = [
            f"{self.source} conversion finished",
            f"  demos read : {self.demos_read}",
            f"  converted  : {self.episodes} episodes, {self.frames} frames",
            f"  skipped    : {len(self.skipped)}",
        ]
        lines += [f"    - {s.source}: {s.reason}" for s in self.skipped]
        lines += [f"  note       : {note}" for note in self.notes]
        lines += [
            f"  output     : {self.output}  (repo id {self.repo_id})",
            f"  time       : {self.seconds:.1f} s ({rate:.2f} demos/s)",
        ]
        return "\n".join(lines)


def demo_rng(seed: int, source: str) -> np.random.Generator:
    """A generator that depends only on the seed and the demo's name, not on which other demos are converted."""
    return np.random.default_rng([seed, zlib.crc32(source.encode())])


def sampling_indices(points: np.ndarray, num_points: int, count: int, rng: np.random.Generator) -> list[np.ndarray]:
    """`count` farthest-point samplings of one cloud, each seeded by a different random start index.

    The same index array is applied to every cloud whose rows correspond (start and goal), so row i of
    the sampled goal is still where row i of the sampled start must go.
    """
    n = points.shape[0]
    starts = rng.choice(n, size=count, replace=count > n)
    return [farthest_point_indices(points, num_points, start_index=int(s)) for s in starts]


def sampled_frames(
    source: str,
    object_points: np.ndarray,
    scene_points: np.ndarray,
    counts: tuple[int, int],
    options: ConversionOptions,
    *,
    goal_points: np.ndarray | None = None,
    transform: np.ndarray | None = None,
) -> list[dict[str, np.ndarray]]:
    """The frames of one demo: `options.frames_per_episode` farthest-point samplings of its clouds.

    The goal rows are taken with the object's indices from `goal_points`, or, for rigid sources, computed
    as `transform` applied to the sampled object, so row i of every goal is where row i of its start goes.
    Samplings depend only on the seed and `source` (see `demo_rng`).
    """
    rng = demo_rng(options.seed, source)
    object_views = sampling_indices(object_points, counts[0], options.frames_per_episode, rng)
    scene_views = sampling_indices(scene_points, counts[1], options.frames_per_episode, rng)
    frames = []
    for object_index, scene_index in zip(object_views, scene_views, strict=True):
        points = object_points[object_index]
        goal = transform_points(transform, points) if goal_points is None else goal_points[object_index]
        frames.append(placement_frame(points, scene_points[scene_index], goal, transform, source=source))
    return frames


def write_dataset(
    demos: Sequence[DemoRef],
    episode: Callable[[DemoRef], tuple[list[dict], str]],
    *,
    source_name: str,
    repo_id: str,
    root: Path,
    features: dict,
    fps: int,
    card: DatasetCardInfo,
    options: ConversionOptions,
    notes: Sequence[str] = (),
) -> ConversionSummary:
    """Convert every demo into one episode and publish the dataset atomically at `root`.

    A bad demo stops the run (nothing is published) unless `options.skip_invalid`, in which case it is
    listed in the summary and the dataset card.
    """
    if not demos:
        raise DemoError(f"{source_name}: no demos to convert (check --raw-dir and --split)")
    started = time.perf_counter()
    with DatasetWriter(repo_id, root, features, fps=fps, card=card, overwrite=options.overwrite) as writer:
        for demo in tqdm(demos, desc=f"{source_name} -> {root.name}", unit="demo", dynamic_ncols=True):
            try:
                frames, task = episode(demo)
                writer.add_episode(frames, task=task)
            except (DemoError, PointCloudError) as exc:
                if not options.skip_invalid:
                    raise
                writer.skip(demo.source, str(exc).removeprefix(f"{demo.source}: "))
        if writer.num_episodes == 0:
            reasons = "; ".join(f"{s.source}: {s.reason}" for s in writer.skipped[:3])
            raise DemoError(f"every one of the {len(demos)} demos was invalid, nothing to write ({reasons})")
    return ConversionSummary(
        source=source_name,
        repo_id=repo_id,
        output=writer.root,
        demos_read=len(demos),
        episodes=writer.num_episodes,
        frames=writer.num_frames,
        skipped=list(writer.skipped),
        seconds=time.perf_counter() - started,
        notes=list(notes),
    )


def card_details(options: ConversionOptions, object_cloud_size: int, scene_cloud_size: int) -> dict[str, str]:
    """Card rows every converter records: how the clouds were sampled and which demos were taken."""
    return {
        "split": options.split,
        "sampling": (
            f"farthest point sampling, {object_cloud_size} object / {scene_cloud_size} scene points; "
            f"{options.frames_per_episode} samplings per demo seeded by random start indices (seed {options.seed})"
        ),
    }
