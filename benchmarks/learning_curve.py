"""How well the paper-size TAX-DPD model places the keyed box against training time, on this machine.

Trains the paper's architecture (hidden 128, 5 DiT blocks, 4 heads) with `lerobot-train` on the two-slot
task at the paper's 512/1024 point counts (bf16 autocast by default), keeps a checkpoint every
`--save-every` steps, then scores each one on held-out scenes: per-point RMSE, winner-take-all RMSE over K,
translation and rotation errors, coverage of both slots and the GMM's mass on the slots. Each row carries
the wall time of training up to that checkpoint. Prints the machine and writes JSON.

    python benchmarks/learning_curve.py                          # results/learning_curve.json
    python benchmarks/learning_curve.py --steps 600 --save-every 200 --object-cloud-size 256
"""

from __future__ import annotations

import argparse
import shlex
import time
from pathlib import Path

import torch

from lerobot_taxdpd import TaxDPDPolicy
from lerobot_taxdpd.apps.slot_demo import parse_args as demo_arguments
from lerobot_taxdpd.apps.slot_demo import prepare_output, train
from lerobot_taxdpd.apps.synthetic import evaluate_slot_predictor, write_slot_dataset
from lerobot_taxdpd.reports.benchmarking import machine_info, write_json


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--save-every", type=int, default=250)
    parser.add_argument("--episodes", type=int, default=256)
    parser.add_argument("--object-cloud-size", type=int, default=512, help="object points per cloud of the data")
    parser.add_argument("--scene-cloud-size", type=int, default=1024, help="scene points per cloud of the data")
    parser.add_argument("--yaw-range", type=float, default=0.5)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--fp32", action="store_true", help="train in fp32 instead of bf16 autocast")
    parser.add_argument("--scenes", type=int, default=24, help="held-out scenes per checkpoint")
    parser.add_argument("--samples", type=int, default=10, help="K goals per scene")
    parser.add_argument("--work-dir", type=Path, default=Path("results/learning_curve"))
    parser.add_argument("--output", default="results/learning_curve.json")
    args = parser.parse_args()

    run = demo_arguments(
        [
            "--output", str(args.work_dir), "--episodes", str(args.episodes), "--steps", str(args.steps),
            "--yaw-range", str(args.yaw_range), "--hidden-dim", "128", "--num-blocks", "5", "--lr", str(args.lr),
            "--object-cloud-size", str(args.object_cloud_size), "--scene-cloud-size", str(args.scene_cloud_size),
        ]
    )
    prepare_output(run.output)
    dataset = write_slot_dataset(
        run.output / "data", episodes=run.episodes, object_cloud_size=run.object_cloud_size,
        scene_cloud_size=run.scene_cloud_size, yaw_range=run.yaw_range, seed=0,
    )
    started = time.time()
    _, command, train_seconds = train(run, dataset, save_freq=args.save_every, use_amp=not args.fp32)
    # The demo marker lets a later run reuse the folder (prepare_output refuses foreign folders).
    write_json(run.output / "metrics.json", {"arguments": {k: str(v) for k, v in vars(run).items()}})

    machine = machine_info()
    print(f"machine: {machine['cpu']} | {machine['cpu_count']} cores | torch {machine['torch']} | "
          f"{machine['torch_threads']} threads | load {machine['load_average_1min']:.1f}")
    task = dict(
        num_scenes=args.scenes, num_samples=args.samples, num_object_points=run.object_cloud_size,
        num_scene_points=run.scene_cloud_size, yaw_range=run.yaw_range,
    )
    rows = []
    for checkpoint in sorted((run.output / "train" / "checkpoints").glob("[0-9]*")):
        model_dir = checkpoint / "pretrained_model"
        policy = TaxDPDPolicy.from_pretrained(model_dir)
        metrics = evaluate_slot_predictor(policy, **task, generator=torch.Generator().manual_seed(0))
        row = {
            "step": int(checkpoint.name),
            "train_seconds": (model_dir / "model.safetensors").stat().st_mtime - started,
            **metrics,
        }
        rows.append(row)
        print(
            f"step {row['step']:>5} ({row['train_seconds'] / 60:5.1f} min): RMSE {row['rmse_mm']:.1f} mm, "
            f"WTA RMSE {row['wta_rmse_mm']:.1f} mm, translation {row['translation_error_mm']:.1f} mm, "
            f"rotation {row['rotation_error_deg']:.1f} deg, "
            f"coverage@{args.samples} {row[f'coverage@{args.samples}']:.2f}, "
            f"GMM mass on slots {row.get('gmm_mass_on_slots', float('nan')):.2f}"
        )
    payload = {
        "machine": machine,
        "config": vars(args) | {"work_dir": str(args.work_dir)},
        "train_seconds": train_seconds,
        "train_command": shlex.join(map(str, command)),
        "results": rows,
    }
    print(f"wrote {write_json(args.output, payload)}")


if __name__ == "__main__":
    main()
