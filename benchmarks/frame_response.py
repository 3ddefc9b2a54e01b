"""Does a goal predictor's local stage find the goal, or stay where its placement frame puts it?

The local stage is trained to undo a frame that is off (`frame_noise_std`), so that a Dense GMM frame a few
millimetres from the slot still gives the slot. On held-out scenes this puts every sample's frame at the
demonstrated goal centroid moved by d along each principal axis of the goal cloud (thinnest first) and reads
where the samples' centroids land along that axis. The slope of landing against d says how much of the offset
passes through: 0, the local stage finds the goal from anywhere within the offsets; 1, it stays where it was
put, and the frame alone decides the position along that axis. Per axis it also prints the error at d = 0 (the
true frame). Prints the machine and config beside the figures and writes JSON.

    python benchmarks/frame_response.py --goal-policy.path book_shelf --task book_shelf
    python benchmarks/frame_response.py --goal-policy.path CHECKPOINT --task book_shelf --split train --seed 0
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from lerobot_taxdpd.goal_predictors import load_goal_predictor
from lerobot_taxdpd.reports.benchmarking import machine_info, write_json
from lerobot_taxdpd.sim.predictors import observed_as_trained
from lerobot_taxdpd.sim.tasks import get_task, task_names
from lerobot_taxdpd.sim.trials import make_trial

AXES = ("thinnest", "middle", "longest")


def landing_offsets(predictor, trial, offsets_m: np.ndarray, num_samples: int, seed: int) -> np.ndarray:
    """(3 axes, len(offsets)) where the samples' mean centroid lands along each principal axis of the goal cloud,
    relative to the demonstrated centroid, with the frames put at the centroid moved by each offset."""
    goal = trial.goal_points().astype(np.float64)
    centroid = goal.mean(0)
    axes = np.linalg.svd(goal - centroid, full_matrices=False)[2][::-1]  # thinnest extent first
    object_points = torch.from_numpy(trial.object_points)[None]
    scene_points = torch.from_numpy(trial.scene_points)[None]
    landing = np.empty((3, len(offsets_m)))
    for a, axis in enumerate(axes):
        for j, offset in enumerate(offsets_m):
            frame = torch.from_numpy(centroid + offset * axis)[None]
            goals = predictor.sample_goals(
                object_points,
                scene_points,
                num_samples,
                generator=torch.Generator().manual_seed(seed),
                placement_frames=frame,
            )
            landing[a, j] = float(((goals[0].double().mean(1).numpy() - centroid) @ axis).mean())
    return landing


def summarise(landings: np.ndarray, offsets_mm: np.ndarray) -> dict:
    """Per axis: the slope of landing on offset (least squares over scenes), the mean landing at each offset
    and the median absolute landing at the true frame."""
    centre = int(np.argmin(np.abs(offsets_mm)))
    summary = {}
    for a, name in enumerate(AXES):
        per_scene = landings[:, a, :] * 1000
        slope = np.polyfit(np.tile(offsets_mm, len(per_scene)), per_scene.ravel(), 1)[0]
        summary[name] = {
            "slope": float(slope),
            "mean_landing_mm": [round(float(v), 2) for v in per_scene.mean(0)],
            "true_frame_error_median_mm": float(np.median(np.abs(per_scene[:, centre]))),
        }
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--goal-policy.path", dest="goal_policy", required=True, help="a shipped name or a folder")
    parser.add_argument("--task", required=True, choices=task_names())
    parser.add_argument("--split", default="test", choices=("train", "test"))
    parser.add_argument("--seed", type=int, default=1000, help="first scene (default: 1000, not the reported 0-99)")
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--offset-mm", type=float, default=13.0, help="largest offset (default: 13, the book's "
                        "training frame noise, 0.3 model units)")
    parser.add_argument("--num-samples", type=int, default=2, help="samples a frame, averaged")
    parser.add_argument("--output", type=Path, default=Path("results/frame_response.json"))
    args = parser.parse_args()
    torch.set_num_threads(1)

    predictor = load_goal_predictor(args.goal_policy)
    task = observed_as_trained(get_task(args.task), predictor)
    offsets_mm = np.linspace(-args.offset_mm, args.offset_mm, 5)
    landings = np.stack(
        [
            landing_offsets(predictor, make_trial(task, seed, args.split), offsets_mm / 1000, args.num_samples, seed)
            for seed in range(args.seed, args.seed + args.trials)
        ]
    )
    summary = summarise(landings, offsets_mm)
    machine = machine_info()
    print(
        f"machine: {machine['cpu']} | {machine['cpu_count']} cores | torch {machine['torch']} | 1 thread | "
        f"load {machine['load_average_1min']:.1f}"
    )
    print(f"{args.goal_policy} on {args.task} ({args.split}, seeds {args.seed}-{args.seed + args.trials - 1}), "
          f"frames at the goal centroid + d along each principal axis, d = {offsets_mm.round(1).tolist()} mm")
    for name, row in summary.items():
        print(f"  {name:9s} slope {row['slope']:5.2f}  mean landing {row['mean_landing_mm']} mm  "
              f"at the true frame {row['true_frame_error_median_mm']:.1f} mm (median)")
    write_json(
        args.output,
        {"machine": machine, "arguments": {k: str(v) for k, v in vars(args).items()}, "offsets_mm": offsets_mm.tolist(),
         "axes": summary, "landings_mm": (landings * 1000).round(3).tolist()},
    )
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
