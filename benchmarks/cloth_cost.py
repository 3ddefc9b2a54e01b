"""Cost of the cloth_hang task and of gc_dp3 inference, and the scripted expert's success rate.

Per split: expert demonstrations of scene seeds seed..seed+N-1 (the (hole, hanger) of each demo as the
dataset generator picks it); success rate with a 95% Wilson interval, seconds per episode, milliseconds
per physics step while the cloth hangs free (approach) and while it is threaded onto a peg (contact),
and the release-and-settle time. gc_dp3: milliseconds to denoise one action chunk from one observation,
for the CPU default and DP3's paper-size U-Net. Medians; machine, load and thread count are written
beside the figures.

    python benchmarks/cloth_cost.py                                  # results/cloth_cost.json
    python benchmarks/cloth_cost.py --seeds 10 --splits train --no-policy
"""

from __future__ import annotations

import argparse
import shlex
import statistics
import sys
import time
from pathlib import Path

import torch
from tqdm import tqdm

from lerobot_taxdpd.maths.metrics import success_summary
from lerobot_taxdpd.reports.benchmarking import machine_info, write_json
from lerobot_taxdpd.sim.cloth.env import ClothHangEnv
from lerobot_taxdpd.sim.cloth.expert import ScriptedExpert
from lerobot_taxdpd.sim.cloth.rollout import demo_target
from lerobot_taxdpd.sim.cloth.scene import SPLITS, sample_scene
from lerobot_taxdpd.threads import add_threads_argument, configure_threads


def expert_costs(split: str, seeds: range) -> dict:
    env = ClothHangEnv(split)
    substeps = env.settings.substeps_per_action
    per_phase: dict[str, list[float]] = {"approach": [], "thread": []}
    episodes, releases, successes = [], [], 0
    try:
        for seed in tqdm(seeds, desc=f"expert episodes ({split})"):
            scene = sample_scene(split, seed, env.ranges)
            started = time.perf_counter()
            env.reset(options={"scene": scene})
            expert = ScriptedExpert(env, *demo_target(scene))
            terminated, step_times = False, []
            while not terminated:
                action, phase = expert.act(), expert.phase
                tick = time.perf_counter()
                _, _, terminated, _, info = env.step(action)
                elapsed = time.perf_counter() - tick
                if terminated:
                    releases.append(elapsed - statistics.median(step_times))
                elif phase in per_phase:
                    per_phase[phase].append(1000.0 * elapsed / substeps)
                step_times.append(elapsed)
            episodes.append(time.perf_counter() - started)
            successes += bool(info["is_success"])
            print(f"  {split} seed {seed}: success={info['is_success']} {episodes[-1]:.1f} s", flush=True)
    finally:
        env.close()
    return {
        **success_summary(successes, len(seeds)),
        "seeds": f"{seeds.start}..{seeds.stop - 1}",
        "seconds_per_episode": statistics.median(episodes),
        "max_seconds_per_episode": max(episodes),
        "ms_per_physics_step_hanging_free": statistics.median(per_phase["approach"]),
        "ms_per_physics_step_in_contact": statistics.median(per_phase["thread"]),
        "release_and_settle_s": statistics.median(releases),
    }


def policy_latency(down_dims: tuple[int, ...], encoder: tuple[int, ...], points_per_cloud: int | None) -> dict:
    """Median ms to denoise one chunk (10 DDIM steps) from one observation of three 512-point clouds."""
    from lerobot.configs.types import FeatureType, PolicyFeature

    from lerobot_taxdpd import GcDp3Config
    from lerobot_taxdpd.data.schema import ACTION_KEY, GOAL_CLOUD_KEY, OBJECT_KEY, SCENE_KEY, STATE_KEY
    from lerobot_taxdpd.policies.gc_dp3.modeling_gc_dp3 import GcDp3Policy

    cloud = PolicyFeature(FeatureType.STATE, (512, 3))
    config = GcDp3Config(
        input_features={
            OBJECT_KEY: cloud,
            SCENE_KEY: cloud,
            GOAL_CLOUD_KEY: cloud,
            STATE_KEY: PolicyFeature(FeatureType.STATE, (12,)),
        },
        output_features={ACTION_KEY: PolicyFeature(FeatureType.ACTION, (6,))},
        down_dims=down_dims,
        point_encoder_dims=encoder,
        points_per_cloud=points_per_cloud,
        device="cpu",
    )
    policy = GcDp3Policy(config).eval()
    observation = {key: torch.randn(1, 512, 3) for key in (OBJECT_KEY, SCENE_KEY, GOAL_CLOUD_KEY)}
    observation[STATE_KEY] = torch.randn(1, 12)
    times = []
    for _ in range(6):
        policy.reset()
        tick = time.perf_counter()
        policy.predict_action_chunk(observation)
        times.append(1000.0 * (time.perf_counter() - tick))
    return {
        "down_dims": list(down_dims),
        "point_encoder_dims": list(encoder),
        "points_per_cloud": points_per_cloud,
        "parameters_millions": sum(p.numel() for p in policy.parameters()) / 1e6,
        "ms_per_chunk": statistics.median(times[1:]),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--splits", nargs="+", default=list(SPLITS), choices=SPLITS)
    parser.add_argument("--seeds", type=int, default=20, help="expert episodes per split")
    parser.add_argument("--seed", type=int, default=1000, help="first scene seed (away from the datasets' seeds)")
    parser.add_argument("--no-policy", action="store_true", help="skip the gc_dp3 latency figures")
    parser.add_argument("--output", type=Path, default=Path("results/cloth_cost.json"))
    add_threads_argument(parser)
    args = parser.parse_args()
    configure_threads(args.threads)
    report = {
        "command": shlex.join([sys.executable, *sys.argv]),
        "machine": machine_info(),
        "config": {"control_hz": 20, "physics_hz": 500, "node_density": 15, "self_collision": False},
        "expert": {},
    }
    print(f"machine: {report['machine']}")
    for split in args.splits:
        report["expert"][split] = expert_costs(split, range(args.seed, args.seed + args.seeds))
    if not args.no_policy:
        report["gc_dp3_inference"] = [
            policy_latency((64, 128, 256), (32, 64, 128), None),
            policy_latency((64, 128, 256), (32, 64, 128), 128),
            policy_latency((512, 1024, 2048), (64, 128, 256), None),
        ]
    path = write_json(args.output, report)
    for split, figures in report["expert"].items():
        print(
            f"expert {split}: success {figures['success_rate']:.2f}"
            f" [{figures['ci95_low']:.2f}, {figures['ci95_high']:.2f}] over {figures['trials']};"
            f" {figures['seconds_per_episode']:.1f} s/episode;"
            f" {figures['ms_per_physics_step_hanging_free']:.2f} ms/step free,"
            f" {figures['ms_per_physics_step_in_contact']:.2f} ms/step in contact"
        )
    for figures in report.get("gc_dp3_inference", []):
        print(
            f"gc_dp3 {figures['down_dims']} ({figures['parameters_millions']:.1f} M): "
            f"{figures['ms_per_chunk']:.0f} ms/chunk"
        )
    print(f"threads: {torch.get_num_threads()}; written to {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
