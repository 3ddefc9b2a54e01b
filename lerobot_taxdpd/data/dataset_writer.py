"""One writer for every dataset the project produces: converters, simulated demos and cloth rollouts.

It writes a LeRobot v3.0 dataset into a hidden partial folder beside the output and moves it into place
only once it is complete, with a dataset card, the dataset's scale statistics (`scaling.SCALE_FILE`) and
which of its clouds are in farthest-point order (`point_order.POINT_ORDER_FILE`);
an error or an interrupt leaves any earlier dataset at the output path untouched. Episodes are validated
whole before any frame is buffered, so a bad demo can be skipped without leaving a half-filled episode behind.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import secrets
import shutil
import signal
import tempfile
import threading
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from lerobot_taxdpd.data.point_order import is_farthest_point_ordered, write_point_order
from lerobot_taxdpd.data.scaling import object_radius, write_scale_stats
from lerobot_taxdpd.data.schema import OBJECT_KEY, SCENE_KEY

CARD_INFO_FILE = "meta/taxdpd_card.json"

logger = logging.getLogger(__name__)


@contextlib.contextmanager
def _interrupts_deferred() -> Iterator[None]:
    """SIGINT and SIGTERM held back until the block ends (then delivered), where the platform allows it."""
    if not hasattr(signal, "pthread_sigmask") or threading.current_thread() is not threading.main_thread():
        yield
        return
    held = {signal.SIGINT, signal.SIGTERM}
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


@dataclass
class DatasetCardInfo:
    """What a reader of the dataset card needs to trust the data."""

    source: str
    source_license: str
    units: str = "metres"
    command: str | None = None
    description: str = ""
    hub_license: str = "other"
    tags: list[str] = field(default_factory=list)
    details: dict[str, str] = field(default_factory=dict)


@dataclass
class SkippedItem:
    source: str
    reason: str


class DatasetWriter:
    """Context manager writing a LeRobot dataset atomically.

    >>> with DatasetWriter("me/ds", "out/ds", features, fps=10, card=card) as writer:
    ...     writer.add_episode(frames, task="hang the mug on the rack")
    ...     writer.skip("demo_7.npz", "field 'action' contains NaN")
    """

    def __init__(
        self,
        repo_id: str,
        root: str | Path,
        features: dict,
        *,
        fps: int,
        card: DatasetCardInfo,
        overwrite: bool = False,
        robot_type: str | None = None,
    ) -> None:
        self.repo_id = repo_id
        self.root = Path(root).absolute()
        self.features = features
        self.fps = fps
        self.card = card
        self.overwrite = overwrite
        self.robot_type = robot_type
        self.num_episodes = 0
        self.num_frames = 0
        self.skipped: list[SkippedItem] = []
        self._object_radii: list[float] = []  # one a frame: the dataset's scale statistics
        # per cloud field the step reduces: every cloud so far in farthest-point order (checked until one is not)
        self._fps_ordered = {key: True for key in (OBJECT_KEY, SCENE_KEY) if key in features}
        self._partial: Path | None = None
        self._dataset = None
        if self.root.exists() and not overwrite:
            raise FileExistsError(
                f"output folder already exists: {self.root} (choose another --root, or add --overwrite to replace it)"
            )

    # ------------------------------------------------------------------------------------ lifecycle
    def __enter__(self) -> DatasetWriter:
        import datasets
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        # One progress bar per saved episode drowns the caller's own progress bar.
        datasets.disable_progress_bars()

        self.root.parent.mkdir(parents=True, exist_ok=True)
        # Named before it is made (64 random bits: no other folder has the name), so that an interrupt arriving
        # the instant the folder exists is inside the `try` that removes it.
        self._partial = self.root.parent / f".{self.root.name}.partial-{secrets.token_hex(8)}"
        try:
            self._partial.mkdir()
            self._dataset = LeRobotDataset.create(
                repo_id=self.repo_id,
                fps=self.fps,
                features=self.features,
                root=self._partial / "dataset",
                robot_type=self.robot_type,
                use_videos=False,
            )
        except BaseException:  # __exit__ does not run when __enter__ fails: remove the partial folder here
            shutil.rmtree(self._partial, ignore_errors=True)
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            self._dataset.finalize()
            if exc_type is None:
                if self.num_episodes == 0:
                    raise ValueError(
                        f"no episodes were written to {self.root}: "
                        + ("; ".join(f"{s.source}: {s.reason}" for s in self.skipped[:5]) or "no input")
                    )
                staged = self._partial / "dataset"
                write_card_info(staged, self.card, self.skipped)
                if self._object_radii:
                    write_scale_stats(staged, self._object_radii)
                if self._fps_ordered:
                    write_point_order(staged, self._fps_ordered)
                write_dataset_card(staged, self.repo_id)
                self._publish(staged)
        finally:
            shutil.rmtree(self._partial, ignore_errors=True)
        return False

    def _publish(self, staged: Path) -> None:
        """Move the finished dataset into place; an existing one is replaced only after it is complete. Ctrl-C
        waits for the two renames, so the output path never stands empty with the old dataset set aside."""
        with _interrupts_deferred():
            if not self.root.exists():
                os.replace(staged, self.root)
                return
            previous = Path(tempfile.mkdtemp(prefix=f".{self.root.name}.previous-", dir=self.root.parent))
            os.replace(self.root, previous / "dataset")
            os.replace(staged, self.root)
        shutil.rmtree(previous, ignore_errors=True)

    # ---------------------------------------------------------------------------------------- writing
    def add_episode(self, frames: Sequence[dict[str, np.ndarray]], task: str) -> None:
        """Validate and write one episode; nothing is buffered unless every frame is valid."""
        from lerobot.datasets.utils import validate_frame

        if self._dataset is None:
            raise RuntimeError("DatasetWriter must be used as a context manager")
        if len(frames) < 2:
            raise ValueError(
                f"an episode needs at least 2 frames (LeRobot 0.4.4 breaks on one-frame episodes), got {len(frames)}"
            )
        if not task:
            raise ValueError("task: a plain-language task string is required")
        for frame in frames:
            validate_frame({**frame, "task": task}, self._dataset.features)
        for frame in frames:
            self._dataset.add_frame({**frame, "task": task})
        self._dataset.save_episode()
        if OBJECT_KEY in self.features:
            clouds = torch.from_numpy(np.stack([frame[OBJECT_KEY] for frame in frames])).double()
            self._object_radii += object_radius(clouds).tolist()
        for key, ordered in self._fps_ordered.items():
            self._fps_ordered[key] = ordered and all(is_farthest_point_ordered(frame[key]) for frame in frames)
        self.num_episodes += 1
        self.num_frames += len(frames)

    def skip(self, source: str, reason: str) -> None:
        """Record an input that was left out; it is listed in the summary and the dataset card."""
        self.skipped.append(SkippedItem(source, reason))
        logger.warning("skipped %s: %s", source, reason)


# ---------------------------------------------------------------------------------------------- cards
def write_card_info(root: Path, card: DatasetCardInfo, skipped: Sequence[SkippedItem]) -> None:
    path = Path(root) / CARD_INFO_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"card": asdict(card), "skipped": [asdict(s) for s in skipped]}
    path.write_text(json.dumps(payload, indent=2))


def read_card_info(root: Path) -> tuple[DatasetCardInfo, list[SkippedItem]]:
    path = Path(root) / CARD_INFO_FILE
    if not path.exists():
        raise FileNotFoundError(f"{path}: no card information (was this dataset written by lerobot_taxdpd?)")
    payload = json.loads(path.read_text())
    return DatasetCardInfo(**payload["card"]), [SkippedItem(**s) for s in payload["skipped"]]


def card_description(root: Path) -> str:
    """Markdown body of the dataset card: provenance, units, point counts, command and skipped inputs."""
    card, skipped = read_card_info(root)
    info = json.loads((Path(root) / "meta" / "info.json").read_text())
    lines = [card.description, "", "| | |", "|---|---|"]
    lines += [f"| source | {card.source} |", f"| licence of the source | {card.source_license} |"]
    lines += [f"| units | {card.units} |"]
    for key, feature in info["features"].items():
        if key.startswith("observation.") or key in ("action", "goal.transform"):
            lines.append(f"| `{key}` | {feature['dtype']} {tuple(feature['shape'])} |")
    lines += [f"| episodes / frames | {info['total_episodes']} / {info['total_frames']} |"]
    lines += [f"| {k} | {v} |" for k, v in card.details.items()]
    if card.command:
        lines += ["", "Produced with:", "", "```bash", card.command, "```"]
    if skipped:
        lines += ["", f"Skipped inputs ({len(skipped)}):", ""]
        lines += [f"- `{s.source}`: {s.reason}" for s in skipped]
    return "\n".join(lines).strip() + "\n"


def _card(root: Path, repo_id: str):
    from lerobot.datasets.utils import create_lerobot_dataset_card

    card, _ = read_card_info(root)
    info = json.loads((Path(root) / "meta" / "info.json").read_text())
    return create_lerobot_dataset_card(
        tags=["taxdpd", "point-cloud", *card.tags],
        dataset_info=info,
        license=card.hub_license,
        repo_id=repo_id,
        dataset_description=card_description(root),
    )


def write_dataset_card(root: Path, repo_id: str) -> Path:
    path = Path(root) / "README.md"
    _card(root, repo_id).save(str(path))
    return path


def push_dataset(root: str | Path, repo_id: str, *, private: bool = False, branch: str | None = None) -> None:
    """Upload a finished dataset with LeRobot's own `push_to_hub` (tags the `v3.0` codebase version)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = Path(root)
    card, _ = read_card_info(root)
    dataset = LeRobotDataset(repo_id, root=root)
    dataset.push_to_hub(
        branch=branch,
        tags=["taxdpd", "point-cloud", *card.tags],
        license=card.hub_license,
        private=private,
        dataset_description=card_description(root),
    )
