"""Training from scratch in a few minutes: make a synthetic two-slot placement dataset, train TAX-DPD with
`lerobot-train`, sample goals on held-out scenes, and write metrics and figures. Offline, CPU.

    taxdpd-demo --synthetic             # results/demo_slots/{metrics.json, goals_*.png, gmm_*.png, train/...}
    taxdpd-demo --synthetic --steps 2000 --yaw-range 3.14 --output results/demo_full
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import time
from pathlib import Path

import numpy as np
import torch

from lerobot_taxdpd.apps.synthetic import evaluate_slot_predictor, make_slot_scene, write_slot_dataset
from lerobot_taxdpd.recipes import run, train_command
from lerobot_taxdpd.reports.benchmarking import machine_info, write_json
from lerobot_taxdpd.threads import add_threads_argument, configure_threads

MARKER = "metrics.json"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="taxdpd-demo --synthetic", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--output", type=Path, default=Path("results/demo_slots"), help="folder for data, checkpoint and report"
    )
    parser.add_argument("--episodes", type=int, default=128, help="training demos (2 point samplings each)")
    parser.add_argument("--steps", type=int, default=800, help="lerobot-train steps")
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--lr", type=float, default=2e-3, help="peak learning rate (cosine schedule, 20 warm-up steps)")
    parser.add_argument("--yaw-range", type=float, default=0.5, help="slot and start yaws lie in +-this (radians)")
    parser.add_argument("--hidden-dim", type=int, default=48)
    parser.add_argument("--num-blocks", type=int, default=2)
    parser.add_argument(
        "--object-cloud-size", type=int, default=64, help="object points per cloud of the data and the held-out scenes"
    )
    parser.add_argument("--scene-cloud-size", type=int, default=128, help="scene points per cloud, likewise")
    parser.add_argument("--samples", type=int, default=8, help="goals sampled per held-out scene")
    parser.add_argument("--scenes", type=int, default=12, help="held-out scenes to evaluate")
    parser.add_argument("--seed", type=int, default=1)
    add_threads_argument(parser)
    return parser.parse_args(argv)


def prepare_output(output: Path, marker: str = MARKER) -> None:
    """Reuse a folder from an earlier run (recognised by its `marker` file); refuse to clobber anything else."""
    if output.exists() and any(output.iterdir()):
        if not (output / marker).exists():
            raise SystemExit(f"{output} exists and is not an earlier demo's output; choose another --output")
        shutil.rmtree(output)
    output.mkdir(parents=True, exist_ok=True)


def train(
    args: argparse.Namespace, dataset: Path, save_freq: int | None = None, use_amp: bool = False
) -> tuple[Path, list[str], float]:
    """Run `lerobot-train` on the slot dataset with the demo's recipe; returns (last checkpoint, command, seconds).

    `save_freq` keeps intermediate checkpoints (default: only the last); `use_amp` trains under bf16 autocast.
    """
    flags = [
        "--policy.type=taxdpd",
        "--policy.push_to_hub=false",
        "--policy.device=cpu",
        f"--policy.hidden_dim={args.hidden_dim}",
        f"--policy.num_blocks={args.num_blocks}",
        "--policy.num_heads=4",
        "--policy.max_neighbors=32",
        f"--policy.optimizer_lr={args.lr}",
        "--policy.scheduler_warmup_steps=20",
        f"--batch_size={args.batch_size}",
        f"--steps={args.steps}",
        f"--policy.use_amp={str(use_amp).lower()}",
        f"--save_freq={save_freq or args.steps}",
        "--log_freq=100",
        "--num_workers=0",
        f"--seed={args.seed}",
    ]
    command = train_command(dataset, "local/taxdpd_slots", args.output / "train", flags=flags)
    seconds = run(command)
    return args.output / "train" / "checkpoints" / "last" / "pretrained_model", command, seconds


def figures(policy, args: argparse.Namespace) -> list[str]:
    from lerobot_taxdpd.reports.plots import plot_goal_samples, plot_weight_map

    rng = np.random.default_rng(4321)
    paths = []
    for index in range(2):
        scene = make_slot_scene(rng, args.object_cloud_size, args.scene_cloud_size, args.yaw_range)
        obj, points = torch.from_numpy(scene.object_points)[None], torch.from_numpy(scene.scene_points)[None]
        generator = torch.Generator().manual_seed(index)
        goals = policy.sample_goals(obj, points, args.samples, generator=generator)[0].numpy()
        weights, means = (x[0].numpy() for x in policy.placement_distribution(obj, points))
        paths.append(
            plot_goal_samples(
                args.output / f"goals_{index}.png",
                scene.scene_points,
                scene.object_points,
                goals,
                valid_goals=list(scene.valid_goals),
                title=f"held-out scene {index}: {args.samples} sampled goals",
            )
        )
        paths.append(
            plot_weight_map(
                args.output / f"gmm_{index}.png",
                scene.scene_points,
                weights,
                means,
                goal_centroids=scene.valid_goals.mean(1),
                title=f"held-out scene {index}: Dense GMM weights",
            )
        )
    return [str(p) for p in paths]


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    configure_threads(args.threads)
    from lerobot_taxdpd import TaxDPDPolicy

    prepare_output(args.output)
    print(f"[1/4] writing {args.episodes} synthetic two-slot demos", flush=True)
    dataset = write_slot_dataset(
        args.output / "data",
        episodes=args.episodes,
        object_cloud_size=args.object_cloud_size,
        scene_cloud_size=args.scene_cloud_size,
        yaw_range=args.yaw_range,
        seed=0,
    )
    print(f"[2/4] training with lerobot-train for {args.steps} steps", flush=True)
    checkpoint, command, train_seconds = train(args, dataset)
    policy = TaxDPDPolicy.from_pretrained(checkpoint)
    print(f"[3/4] sampling {args.samples} goals on {args.scenes} held-out scenes", flush=True)
    task = dict(
        num_samples=args.samples,
        num_object_points=args.object_cloud_size,
        num_scene_points=args.scene_cloud_size,
        yaw_range=args.yaw_range,
        num_scenes=args.scenes,
    )
    started = time.perf_counter()
    metrics = evaluate_slot_predictor(policy, **task, generator=torch.Generator().manual_seed(0))
    sampling_seconds = time.perf_counter() - started
    print("[4/4] writing figures and metrics", flush=True)
    report = {
        "task": "synthetic keyed box into one of two keyed slots (lerobot_taxdpd.apps.synthetic)",
        "metrics": metrics,
        "train_seconds": train_seconds,
        "evaluation_seconds": sampling_seconds,
        "checkpoint": str(checkpoint),
        "train_command": shlex.join(map(str, command)),
        "figures": figures(policy, args),
        "machine": machine_info(),
        "arguments": {k: str(v) for k, v in vars(args).items()},
    }
    write_json(args.output / MARKER, report)
    print(json.dumps(metrics, indent=2))
    print(f"trained in {train_seconds:.0f} s; report: {args.output / MARKER}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
