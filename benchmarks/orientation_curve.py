"""Orientation learning curves: rotation error against CPU-minutes on the two-slot task at full yaw.

Every variant (a set of `TaxDPDConfig` overrides) trains from the same data with the same training seeds
and is scored on the same held-out scenes, so rows are paired. Training runs the policy's own `forward`
with LeRobot's optimizer and scheduler presets in this process (no data-loader overhead), so the clock
measures the model. Beside every row: the "copy the start orientation" and "mean pose" baselines, and the
equivariance probe (goal turn when the scene alone, or the object alone, is turned by 20 deg).

    python benchmarks/orientation_curve.py --variant noise prediction_type=epsilon \\
        --variant sample prediction_type=sample --steps 3000 --eval-every 500 --seeds 0 1
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np
import torch

from lerobot_taxdpd import TaxDPDConfig, TaxDPDPolicy
from lerobot_taxdpd.apps.synthetic import (
    copy_start_rotation_deg,
    evaluate_slot_predictor,
    make_slot_scene,
    render_slot_scene,
    sample_slot_layout,
)
from lerobot_taxdpd.data.scaling import object_radius
from lerobot_taxdpd.data.schema import ACTION_KEY, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.maths.equivariance import goal_turn_response
from lerobot_taxdpd.reports.benchmarking import machine_info, write_json

# The CI learning test's small model; variants override any field.
BASE = dict(hidden_dim=32, num_blocks=1, num_heads=4, max_neighbors=32, optimizer_lr=2e-3, scheduler_warmup_steps=20)


def parse_value(field: dataclasses.Field, text: str):
    default = field.default if field.default is not dataclasses.MISSING else field.default_factory()
    if isinstance(default, bool):
        return text.lower() in ("1", "true", "yes")
    if isinstance(default, tuple):
        return tuple(type(default[0])(v) for v in text.split(","))
    if default is None:
        return None if text == "none" else float(text)
    return type(default)(text)


def parse_variant(tokens: list[str]) -> tuple[str, dict]:
    fields = {f.name: f for f in dataclasses.fields(TaxDPDConfig)}
    name, overrides = tokens[0], {}
    for token in tokens[1:]:
        key, _, value = token.partition("=")
        if key not in fields:
            raise SystemExit(f"--variant {name}: unknown config field {key!r}")
        overrides[key] = parse_value(fields[key], value)
    return name, overrides


def slot_data(episodes: int, frames: int, n_o: int, n_s: int, yaw_range: float, seed: int) -> dict[str, torch.Tensor]:
    rng = np.random.default_rng(seed)
    rows = {OBJECT_KEY: [], SCENE_KEY: [], ACTION_KEY: []}
    for _ in range(episodes):
        layout = sample_slot_layout(rng, yaw_range)
        for _ in range(frames):
            s = render_slot_scene(layout, rng, n_o, n_s)
            rows[OBJECT_KEY].append(s.object_points)
            rows[SCENE_KEY].append(s.scene_points)
            rows[ACTION_KEY].append(s.goal_points)
    return {k: torch.from_numpy(np.stack(v)) for k, v in rows.items()}


def baselines(args) -> dict[str, float]:
    """Median rotation error of copying the start orientation, and of the mean pose (slot-frame mean)."""
    rng = np.random.default_rng(args.eval_seed)
    scenes = [
        make_slot_scene(rng, args.num_object_points, args.num_scene_points, args.yaw_range) for _ in range(args.scenes)
    ]
    return {
        "copy_start_rotation_deg": copy_start_rotation_deg(scenes),
        "mean_pose_rotation_deg": 90.0 if args.yaw_range >= math.pi else float("nan"),
    }


def evaluate(policy, args) -> dict[str, float]:
    policy.eval()
    task = dict(
        num_scenes=args.scenes,
        num_samples=args.samples,
        num_object_points=args.num_object_points,
        num_scene_points=args.num_scene_points,
        yaw_range=args.yaw_range,
        seed=args.eval_seed,
    )
    metrics = evaluate_slot_predictor(policy, **task, generator=torch.Generator().manual_seed(0))
    rng = np.random.default_rng(args.eval_seed + 1)
    probe = [make_slot_scene(rng, args.num_object_points, args.num_scene_points, args.yaw_range) for _ in range(8)]
    obj = torch.from_numpy(np.stack([s.object_points for s in probe]))
    scene = torch.from_numpy(np.stack([s.scene_points for s in probe]))
    metrics |= {f"turn_{k}_deg": v for k, v in goal_turn_response(policy, obj, scene, num_samples=2).items()}
    policy.train()
    return metrics


def train_variant(name: str, overrides: dict, seed: int, data: dict, args) -> list[dict]:
    torch.manual_seed(seed)
    config = TaxDPDConfig.for_point_clouds(
        args.num_object_points, args.num_scene_points, device="cpu", **(BASE | overrides)
    )
    config.point_scale = config.object_scale / float(object_radius(data[OBJECT_KEY].double()).median())
    policy = TaxDPDPolicy(config).train()
    optimizer = config.get_optimizer_preset().build(policy.get_optim_params())
    scheduler = config.get_scheduler_preset().build(optimizer, args.steps)
    generator = torch.Generator().manual_seed(seed)
    n = data[OBJECT_KEY].shape[0]
    rows, cpu = [], 0.0
    for step in range(1, args.steps + 1):
        started = time.process_time()
        index = torch.randint(0, n, (args.batch_size,), generator=generator)
        loss, _ = policy.forward({k: v[index] for k, v in data.items()})
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), config.optimizer_grad_clip_norm)
        optimizer.step()
        scheduler.step()
        cpu += time.process_time() - started
        if step % args.eval_every == 0 or step == args.steps:
            row = {
                "variant": name,
                "seed": seed,
                "step": step,
                "cpu_minutes": cpu / 60,
                "loss": loss.item(),
            } | evaluate(policy, args)
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--variant",
        nargs="+",
        action="append",
        required=True,
        metavar="NAME KEY=VALUE",
        help="a row: a name, then TaxDPDConfig overrides (repeat for more rows)",
    )
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--eval-every", type=int, default=500)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--episodes", type=int, default=128)
    parser.add_argument("--num-object-points", type=int, default=64)
    parser.add_argument("--num-scene-points", type=int, default=128)
    parser.add_argument("--yaw-range", type=float, default=math.pi)
    parser.add_argument("--scenes", type=int, default=24, help="held-out scenes per evaluation")
    parser.add_argument("--samples", type=int, default=8)
    parser.add_argument("--eval-seed", type=int, default=1234)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--output", type=Path, default=Path("results/orientation_curve.json"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    data = slot_data(args.episodes, 2, args.num_object_points, args.num_scene_points, args.yaw_range, seed=0)
    reference = baselines(args)
    print(json.dumps({"baselines": reference}), flush=True)
    rows = []
    for tokens in args.variant:
        name, overrides = parse_variant(tokens)
        for seed in args.seeds:
            rows += train_variant(name, overrides, seed, data, args)
    payload = {
        "machine": machine_info(),
        "arguments": {k: str(v) for k, v in vars(args).items()},
        "base_config": BASE,
        "baselines": reference,
        "rows": rows,
    }
    print(f"wrote {write_json(args.output, payload)}")


if __name__ == "__main__":
    main()
