"""Look at the data and the predictions in 3-D, with rerun (installed with LeRobot):

    python -m lerobot_taxdpd.viewer dataset --root data/mug_easyrack --episode 0
    python -m lerobot_taxdpd.viewer trial --task mug_multi_medrack --goal-policy.path mug_easyrack --seed 0 \\
        --num-samples 10
    python -m lerobot_taxdpd.viewer ... --save view.rrd     # no display needed; open later with `rerun view.rrd`

`dataset` shows one episode of a dataset of this package's schema (goal prediction or gc_dp3), frame by
frame: every point-cloud feature, the start-to-goal correspondence, the grippers and every other number
(LeRobot's `lerobot-dataset-viz` expects images and 1-D actions and fails on point-cloud datasets).
`trial` builds a simulated scene exactly as `sim eval --seed S` does, samples K goals exactly as it does
(same seed, same numbers), and shows the scene coloured by the Dense GMM's weight, the valid goals, every
sample with its number, the first sample executed (where the object ended up) and the trial's errors.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np
import rerun as rr

from lerobot_taxdpd.data.schema import ACTION_KEY, GOAL_CLOUD_KEY, OBJECT_KEY, SCENE_KEY, STATE_KEY
from lerobot_taxdpd.threads import add_threads_argument, configure_threads

APPLICATION = "lerobot_taxdpd"
#: Colours (RGB) of what every view shows.
GREY, BLUE, GREEN, RED = (150, 150, 150), (31, 119, 180), (44, 160, 44), (214, 39, 40)
CLOUD_COLOURS = {SCENE_KEY: GREY, OBJECT_KEY: BLUE, ACTION_KEY: GREEN, GOAL_CLOUD_KEY: GREEN}
CORRESPONDENCES = 48  # start-to-goal arrows drawn per frame


def _radius(points: np.ndarray) -> float:
    """A point size that reads at the cloud's own scale (mm connectors and metre cloths alike)."""
    return float(np.ptp(points, axis=0).max()) / 150


def _sample_colours(count: int) -> np.ndarray:
    from lerobot_taxdpd.reports.plots import SAMPLE_COLOURS

    return (SAMPLE_COLOURS[np.arange(count) % len(SAMPLE_COLOURS), :3] * 255).astype(np.uint8)


def log_dataset_episode(root: Path, episode: int, repo_id: str) -> int:
    """Log every frame of one episode on the `frame_index` timeline; returns the number of frames."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.datasets.utils import DEFAULT_FEATURES

    if not (Path(root) / "meta" / "info.json").is_file():  # else LeRobot would look for it on the Hub
        raise FileNotFoundError(f"--root: {root} is not a LeRobot dataset folder (no meta/info.json)")
    meta = LeRobotDatasetMetadata(repo_id, root=root)
    if not 0 <= episode < meta.total_episodes:
        raise ValueError(f"--episode: {root} has episodes 0..{meta.total_episodes - 1}, got {episode}")
    dataset = LeRobotDataset(repo_id, root=root, episodes=[episode])
    clouds = [key for key, ft in meta.features.items() if len(ft["shape"]) == 2 and ft["shape"][1] == 3]
    numbers = [
        key
        for key, ft in meta.features.items()
        if key not in DEFAULT_FEATURES and len(ft["shape"]) == 1 and ft["dtype"].startswith("float")
    ]
    for index in range(len(dataset)):
        frame = {key: value.numpy() if hasattr(value, "numpy") else value for key, value in dataset[index].items()}
        rr.set_time("frame_index", sequence=int(frame["frame_index"]))
        if index == 0:
            rr.log("task", rr.TextDocument(f"episode {episode} of {root}\n\n{frame['task']}"), static=True)
        radius = _radius(np.concatenate([frame[key] for key in clouds]))
        for key in clouds:
            colour = CLOUD_COLOURS.get(key, RED)
            rr.log(key, rr.Points3D(frame[key], colors=colour, radii=radius))
        if ACTION_KEY in clouds and OBJECT_KEY in clouds:  # row i of the goal is where point i goes
            start, goal = frame[OBJECT_KEY], frame[ACTION_KEY]
            rows = np.linspace(0, len(start) - 1, min(CORRESPONDENCES, len(start))).astype(int)
            rr.log("correspondence", rr.Arrows3D(origins=start[rows], vectors=goal[rows] - start[rows], colors=GREY))
        if STATE_KEY in numbers and frame[STATE_KEY].shape == (12,):  # gc_dp3: both grippers' positions first
            grippers = frame[STATE_KEY][:6].reshape(2, 3)
            rr.log("grippers", rr.Points3D(grippers, colors=RED, radii=4 * radius, labels=["left", "right"]))
        for key in numbers:
            for dim, value in enumerate(np.atleast_1d(frame[key])):
                rr.log(f"plots/{key}/{dim}", rr.Scalars(float(value)))
        if "goal.transform" in frame:
            rr.log("goal.transform", rr.TextDocument(np.array2string(frame["goal.transform"], precision=4)))
    return len(dataset)


def log_trial(task_name: str, goal_policy_path: str, seed: int, split: str, num_samples: int, device: str) -> dict:
    """Log one simulated trial with the predictor's K goals; returns the trial's record (as `sim eval`'s)."""
    import torch

    from lerobot_taxdpd.goal_predictors import has_placement_distribution, load_goal_predictor
    from lerobot_taxdpd.maths.geometry import transform_points
    from lerobot_taxdpd.sim.harness import run_trial
    from lerobot_taxdpd.sim.tasks import get_task
    from lerobot_taxdpd.sim.trials import make_trial

    trial = make_trial(get_task(task_name), seed, split)
    predictor = load_goal_predictor(goal_policy_path, device=device)
    run = run_trial(predictor, trial, num_samples)
    scene, start = trial.scene_points, trial.object_points
    radius = _radius(np.concatenate([scene, start]))
    rr.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    scene_colours = GREY
    if has_placement_distribution(predictor):
        import matplotlib

        with torch.inference_mode():
            weights, means = predictor.placement_distribution(
                torch.from_numpy(start)[None], torch.from_numpy(scene)[None]
            )
        log_weights = np.log10(np.clip(weights[0].float().cpu().numpy(), 1e-8, None))
        span = max(log_weights.max() - log_weights.min(), 1e-6)
        scene_colours = matplotlib.colormaps["viridis"]((log_weights - log_weights.min()) / span)[:, :3] * 255
        heaviest = np.argsort(log_weights)[-10:]
        rr.log("gmm/heaviest_means", rr.Points3D(means[0].cpu().numpy()[heaviest], colors=RED, radii=2 * radius))
    rr.log("scene", rr.Points3D(scene, colors=np.asarray(scene_colours, dtype=np.uint8), radii=radius))
    rr.log("object/start", rr.Points3D(start, colors=BLUE, radii=radius))
    for mode, transforms in zip(trial.modes, trial.valid_transforms(), strict=True):
        for variant, transform in enumerate(transforms):
            goal = transform_points(transform, start.astype(np.float64))
            path = f"valid_goals/{mode.label.replace(' ', '_')}/{variant}"
            rr.log(path, rr.Points3D(goal, colors=GREEN, radii=radius))
    colours = _sample_colours(len(run.samples))
    for k, (sample, colour) in enumerate(zip(run.samples, colours, strict=True)):
        rr.log(f"samples/{k + 1}", rr.Points3D(sample, colors=colour, radii=radius))
        label = f"sample {k + 1}" + (" (executed)" if k == 0 else "")
        rr.log(f"samples/{k + 1}/label", rr.Points3D(sample.mean(0, keepdims=True), colors=colour, labels=[label]))
    placed = transform_points(run.outcome.final_pose @ np.linalg.inv(trial.start_pose), start.astype(np.float64))
    rr.log("object/after_executing_sample_1", rr.Points3D(placed, colors=RED, radii=radius))
    verdict = "succeeded" if run.outcome.success else f"failed: {run.outcome.reason}"
    errors = "\n".join(f"- {key}: {value}" for key, value in run.record.items())
    rr.log(
        "summary",
        rr.TextDocument(f"{task_name}, {split} seed {seed}, K = {num_samples}: sample 1 {verdict}\n\n{errors}"),
        static=True,
    )
    return run.record


def _open_sink(save: Path | None) -> None:
    rr.init(APPLICATION)
    if save is not None:
        save.parent.mkdir(parents=True, exist_ok=True)
        rr.save(save)
        return
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ValueError("no display to open the rerun viewer on: pass --save PATH and open it with `rerun PATH`")
    rr.spawn()


def _discard_recording(save: Path | None) -> None:
    """A failed view leaves no stub recording that would pass for a finished one."""
    if save is not None:
        rr.disconnect()
        save.unlink(missing_ok=True)


def build_parser() -> argparse.ArgumentParser:
    from lerobot_taxdpd.sim.tasks import task_names

    parser = argparse.ArgumentParser(
        prog="python -m lerobot_taxdpd.viewer",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    views = parser.add_subparsers(dest="view", required=True)
    dataset = views.add_parser("dataset", help="one episode of a LeRobot dataset of this package's schema")
    dataset.add_argument("--root", type=Path, required=True, help="the dataset folder")
    dataset.add_argument("--episode", type=int, default=0, help="episode index (default: 0)")
    dataset.add_argument("--repo-id", default="local/dataset", help="only names it (default: local/dataset)")
    trial = views.add_parser("trial", help="a simulated trial with a goal predictor's K goals")
    trial.add_argument("--task", required=True, choices=task_names())
    trial.add_argument(
        "--goal-policy.path",
        dest="goal_policy_path",
        metavar="NAME_OR_PATH",
        required=True,
        help="TAX-DPD goal predictor: a shipped name, a checkpoint folder or a Hub id",
    )
    trial.add_argument("--seed", type=int, default=0, help="scene seed (as sim eval's trial SEED; default: 0)")
    trial.add_argument("--split", choices=("train", "test"), default="test", help="geometry split (default: test)")
    trial.add_argument("--num-samples", type=int, default=10, help="goals sampled, K (default: 10)")
    trial.add_argument("--device", default="cpu", help="where the predictor runs: cpu, cuda, ... (default: cpu)")
    for view in (dataset, trial):
        view.add_argument("--save", type=Path, default=None, help="write a rerun recording (.rrd) instead of a window")
        add_threads_argument(view)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_threads(args.threads)
    try:
        _open_sink(args.save)
        if args.view == "dataset":
            frames = log_dataset_episode(args.root, args.episode, args.repo_id)
            print(f"episode {args.episode} of {args.root}: {frames} frames")
        else:
            record = log_trial(args.task, args.goal_policy_path, args.seed, args.split, args.num_samples, args.device)
            print(f"{args.task} seed {args.seed}: sample 1 {'succeeded' if record['success'] else 'failed'}")
    except (ValueError, FileNotFoundError) as error:
        print(f"error: {error}", file=sys.stderr)
        _discard_recording(args.save)
        return 1
    if args.save is not None:
        rr.disconnect()  # flush the recording to the file
        print(f"recording: {args.save} (open it with `rerun {args.save}`)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
