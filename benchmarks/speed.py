"""Training throughput and goal-sampling latency of the paper-size TAX-DPD model, against this machine's peak.

For each point count of the paper (512/512, 512/1024, 256/1024) and each precision (fp32, bf16 autocast):
training samples per second (forward + backward + AdamW, batch 16), goal-sampling latency for K = 1 and
K = 10 samples of one scene with the default few-step DDIM sampler, the model's matmul FLOPs per training
sample and per sampling call (counted by torch's FlopCounterMode), and the measured matmul peak of this
machine, so the fraction of peak is visible. Prints everything with the machine and thread count and writes
JSON.

    python benchmarks/speed.py                           # results/speed.json
    python benchmarks/speed.py --configs 512x1024 --repeats 3 --threads 2
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from torch.nn.attention import SDPBackend, sdpa_kernel
from torch.utils.flop_counter import FlopCounterMode

from lerobot_taxdpd import TaxDPDConfig, TaxDPDPolicy
from lerobot_taxdpd.apps.synthetic import make_slot_scene
from lerobot_taxdpd.data.schema import ACTION_KEY, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.reports.benchmarking import machine_info, timed, write_json

# The authors' development code on this CPU (same batch and point counts), for comparison.
REFERENCE = {"train_step_s_512x1024_batch16": 2.2, "sample_s_512x1024_k10": 48.0}


def matmul_gflops(dtype: torch.dtype, size: int, repeats: int) -> float:
    a, b = torch.randn(size, size, dtype=dtype), torch.randn(size, size, dtype=dtype)
    median, _ = timed(lambda: a @ b, repeats)
    return 2 * size**3 / median / 1e9


def scenes(batch: int, num_object_points: int, num_scene_points: int) -> dict[str, torch.Tensor]:
    rng = np.random.default_rng(0)
    data = [make_slot_scene(rng, num_object_points, num_scene_points) for _ in range(batch)]
    return {
        OBJECT_KEY: torch.from_numpy(np.stack([d.object_points for d in data])),
        SCENE_KEY: torch.from_numpy(np.stack([d.scene_points for d in data])),
        ACTION_KEY: torch.from_numpy(np.stack([d.goal_points for d in data])),
    }


def flops(run) -> float:
    """Matmul FLOPs of one call. Attention runs on the math backend while counting, because the counter
    has no formula for the CPU flash-attention kernel and would silently leave attention out."""
    with sdpa_kernel(SDPBackend.MATH), FlopCounterMode(display=False) as counter:
        run()
    return float(counter.get_total_flops())


def benchmark(num_object_points: int, num_scene_points: int, amp: bool, args) -> dict:
    torch.manual_seed(0)
    config = TaxDPDConfig.for_point_clouds(
        num_object_points,
        num_scene_points,
        point_scale=66.0,
        use_amp=amp,
        device="cpu",
        num_inference_steps=args.inference_steps,
    )
    policy = TaxDPDPolicy(config)
    optimizer = torch.optim.AdamW(policy.parameters(), lr=1e-4)
    batch = scenes(args.batch_size, num_object_points, num_scene_points)

    def train_step() -> None:
        policy.train()
        loss, _ = policy.forward(batch)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()

    step_s, step_times = timed(train_step, args.repeats)
    train_flops = flops(train_step) / args.batch_size
    policy.eval()
    obj, scene = batch[OBJECT_KEY][:1], batch[SCENE_KEY][:1]
    sampling = {}
    for k in (1, 10):
        latency, times = timed(lambda k=k: policy.sample_goals(obj, scene, k), args.repeats)
        sampling[f"K={k}"] = {
            "latency_s": latency,
            "all_s": times,
            "gflop": flops(lambda k=k: policy.sample_goals(obj, scene, k)) / 1e9,
        }
    return {
        "points": f"{num_object_points}/{num_scene_points}",
        "precision": "bf16-autocast" if amp else "fp32",
        "train": {
            "batch_size": args.batch_size,
            "step_s": step_s,
            "all_step_s": step_times,
            "samples_per_s": args.batch_size / step_s,
            "gflop_per_sample": train_flops / 1e9,
            "achieved_gflops": train_flops * args.batch_size / step_s / 1e9,
        },
        "sampling": sampling,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--configs", default="512x512,512x1024,256x1024", help="object x scene point counts")
    parser.add_argument("--precisions", default="fp32,bf16")
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--inference-steps", type=int, default=TaxDPDConfig.num_inference_steps)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--output", default="results/speed.json")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)

    peak = {
        "fp32": matmul_gflops(torch.float32, 2048, args.repeats),
        "bf16": matmul_gflops(torch.bfloat16, 2048, args.repeats),
    }
    machine = machine_info()
    print(
        f"machine: {machine['cpu']} | {machine['cpu_count']} cores | torch {machine['torch']} | "
        f"{machine['torch_threads']} threads | load {machine['load_average_1min']:.1f}"
    )
    print(f"matmul peak (2048^3): fp32 {peak['fp32']:.0f} GFLOP/s, bf16 {peak['bf16']:.0f} GFLOP/s")
    print(
        f"model: paper size (hidden 128, 5 DiT blocks, 4 heads), batch {args.batch_size}, "
        f"DDIM {args.inference_steps} steps"
    )
    results = []
    for spec in args.configs.split(","):
        n_o, n_s = (int(x) for x in spec.split("x"))
        for precision in args.precisions.split(","):
            r = benchmark(n_o, n_s, precision == "bf16", args)
            fraction = r["train"]["achieved_gflops"] / peak["bf16" if precision == "bf16" else "fp32"]
            r["train"]["fraction_of_peak"] = fraction
            results.append(r)
            print(
                f"{r['points']:>9} {r['precision']:>13}: train {r['train']['step_s']:.3f} s/step "
                f"({r['train']['samples_per_s']:.1f} samples/s, {r['train']['gflop_per_sample']:.2f} GFLOP/sample, "
                f"{r['train']['achieved_gflops']:.0f} GFLOP/s = {100 * fraction:.0f}% of peak) | "
                f"sample K=1 {r['sampling']['K=1']['latency_s']:.3f} s, K=10 {r['sampling']['K=10']['latency_s']:.3f} s"
            )
    path = write_json(
        args.output,
        {
            "machine": machine,
            "matmul_peak_gflops": peak,
            "config": vars(args),
            "reference_authors_code": REFERENCE,
            "results": results,
        },
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
