"""Few-step sampling against the full 100-step sampler on the two-slot learning task.

Evaluates one trained checkpoint (default: the one `taxdpd-demo --synthetic` writes) with ancestral DDPM over all
100 steps and with DDIM at fewer steps: winner-take-all RMSE over K samples, translation and rotation
errors, coverage, and the latency of one call for the whole batch of held-out scenes. Prints the machine
and writes JSON.

    taxdpd-demo --synthetic && python benchmarks/sampler_quality.py       # results/sampler_quality.json
    python benchmarks/sampler_quality.py --checkpoint PATH --scenes 32 --samples 10
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import torch

from lerobot_taxdpd import TaxDPDPolicy
from lerobot_taxdpd.apps.synthetic import evaluate_slot_predictor
from lerobot_taxdpd.reports.benchmarking import machine_info, write_json
from lerobot_taxdpd.threads import add_threads_argument, configure_threads

SAMPLERS = (("ddpm", 100), ("ddim", 100), ("ddim", 20), ("ddim", 10), ("ddim", 5), ("ddim", 3))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--checkpoint", type=Path, default=Path("results/demo_slots/train/checkpoints/last/pretrained_model")
    )
    parser.add_argument("--scenes", type=int, default=24)
    parser.add_argument("--samples", type=int, default=10)
    parser.add_argument("--yaw-range", type=float, default=None, help="default: the demo's, from its report")
    parser.add_argument("--output", default="results/sampler_quality.json")
    add_threads_argument(parser)
    args = parser.parse_args()
    configure_threads(args.threads)

    policy = TaxDPDPolicy.from_pretrained(args.checkpoint)
    demo_report = args.checkpoint.parents[3] / "metrics.json"
    yaw_range = args.yaw_range
    if yaw_range is None:
        yaw_range = (
            float(json.loads(demo_report.read_text())["arguments"]["yaw_range"]) if demo_report.exists() else math.pi
        )
    shape = policy.config.input_features
    task = dict(
        num_scenes=args.scenes,
        num_samples=args.samples,
        num_object_points=shape["observation.pointcloud.object"].shape[0],
        num_scene_points=shape["observation.pointcloud.scene"].shape[0],
        yaw_range=yaw_range,
    )
    machine = machine_info()
    print(
        f"machine: {machine['cpu']} | torch {machine['torch']} | {machine['torch_threads']} threads | "
        f"load {machine['load_average_1min']:.1f}"
    )
    print(f"checkpoint: {args.checkpoint} | {args.scenes} held-out scenes x K={args.samples}")
    rows = []
    for sampler, steps in SAMPLERS:
        started = time.perf_counter()
        metrics = evaluate_slot_predictor(
            policy, **task, sampler=sampler, num_inference_steps=steps, generator=torch.Generator().manual_seed(0)
        )
        rows.append({"sampler": sampler, "steps": steps, "seconds": time.perf_counter() - started, **metrics})
    reference = rows[0]["wta_rmse_mm"]
    for row in rows:
        row["wta_rmse_vs_ddpm100"] = row["wta_rmse_mm"] / reference
        print(
            f"{row['sampler']:>4} {row['steps']:>3} steps: WTA RMSE {row['wta_rmse_mm']:.2f} mm "
            f"({100 * (row['wta_rmse_vs_ddpm100'] - 1):+.0f}% vs DDPM-100), "
            f"translation {row['translation_error_mm']:.2f} mm, rotation {row['rotation_error_deg']:.2f} deg, "
            f"coverage@{args.samples} {row[f'coverage@{args.samples}']:.2f}, "
            f"{row['seconds']:.1f} s"
        )
    path = write_json(
        args.output, {"machine": machine, "checkpoint": str(args.checkpoint), "task": task, "results": rows}
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
