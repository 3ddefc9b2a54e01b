"""Training and sampling speed of TAX-DPD against this machine's matmul peak, with where the time goes.

For each model (the shipped CPU recipe and the paper's size): one training step in the policy (forward,
backward, AdamW; batch 16) with its breakdown by stage (Dense GMM, point encoders, DiTs, rest of the
forward, backward, optimizer), the same step through `lerobot-train` (its own log's update and data
times), FLOPs a sample (FlopCounterMode, attention counted on the math backend), the fraction of the
matmul peak, and goal-sampling latency for K = 1 and K = 10. Medians of `--repeats`; machine, threads and
config are printed beside the figures and written to JSON.

Launches: the kernel-launching aten ops and host syncs of one training step (as lerobot-train runs it:
forward, backward, gradient clipping, the optimizer, `update()`) and of one K = 10 sampling call, by stage,
counted with every CPU-only shortcut on its device path, so the figures are what a GPU would launch
(`lerobot_taxdpd.reports.launches`), on clouds of the size the datasets record (`RECORDED_POINTS`), so that
the step's reduction to the network's point count is counted too. They do not depend on the machine or its load.

    python benchmarks/speed.py                                  # results/speed.json
    python benchmarks/speed.py --models cpu --repeats 7 --threads 2
    python benchmarks/speed.py --models cpu --set max_neighbors=16 use_amp=true   # a variant
    python benchmarks/speed.py --models cpu --dataset data/mug_easyrack          # lerobot-train on real demos

Every figure is taken on clouds of the size the datasets record (`RECORDED_POINTS`), reduced to the network's
point counts in every step as in training; the `lerobot-train` figure on a small synthetic dataset of that size
unless `--dataset` names a task's demonstrations.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import torch
from torch.nn.attention import SDPBackend, sdpa_kernel
from torch.profiler import ProfilerActivity, profile, record_function
from torch.utils.flop_counter import FlopCounterMode

from lerobot_taxdpd import TaxDPDConfig, TaxDPDPolicy
from lerobot_taxdpd.apps.synthetic import make_slot_scene, write_slot_dataset
from lerobot_taxdpd.data.schema import ACTION_KEY, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.maths.geometry import device_code_paths, farthest_point_indices
from lerobot_taxdpd.policies.taxdpd.model.dit import DiT
from lerobot_taxdpd.policies.taxdpd.model.pointnet2 import PointMLPEncoder, PointNet2Encoder
from lerobot_taxdpd.recipes import add_policy_overrides_argument, recipe_path
from lerobot_taxdpd.reports.benchmarking import machine_info, timed, write_json
from lerobot_taxdpd.reports.launches import LaunchCounter

# The authors' development code on this CPU (2 threads, idle; batch 16, 512/1024 points), for comparison.
REFERENCE = {"local_step_s": 2.24, "gmm_step_s": 3.92, "both_steps_s": 6.16, "sample_k10_s": 48.1}
PAPER = dict(hidden_dim=128, num_blocks=5, num_heads=4, max_neighbors=64, num_object_points=512, num_scene_points=1024)
# The clouds as the datasets record them, which is how lerobot-train feeds the step (a larger cloud is reduced in
# it): the procedural tasks record 512 / 512 points, RPDiff conversions the paper's counts.
RECORDED_POINTS = {"cpu": (512, 512), "paper": (512, 1024)}
STAGES = {"gmm": "global_stage", "encoders": (PointNet2Encoder, PointMLPEncoder), "dit": DiT}


def model_config(name: str, overrides: dict) -> dict:
    if name == "paper":
        fields = dict(PAPER, use_amp=True)
    else:
        recipe = json.loads(recipe_path("taxdpd_cpu").read_text())["policy"]
        fields = {k: v for k, v in recipe.items() if k not in ("type", "device", "push_to_hub")}
    return fields | overrides


def matmul_gflops(dtype: torch.dtype, size: int, repeats: int) -> float:
    a, b = torch.randn(size, size, dtype=dtype), torch.randn(size, size, dtype=dtype)
    median, _ = timed(lambda: a @ b, repeats)
    return 2 * size**3 / median / 1e9


def slot_batch(batch: int, n_o: int, n_s: int) -> dict[str, torch.Tensor]:
    """Slot scenes with clouds as the tasks record them: reduced from denser samplings by FPS, so in FPS order."""
    rng = np.random.default_rng(0)
    clouds = {OBJECT_KEY: [], SCENE_KEY: [], ACTION_KEY: []}
    for _ in range(batch):
        scene = make_slot_scene(rng, 2 * n_o, 2 * n_s)
        keep = farthest_point_indices(scene.object_points, n_o)
        clouds[OBJECT_KEY].append(scene.object_points[keep])
        clouds[ACTION_KEY].append(scene.goal_points[keep])
        clouds[SCENE_KEY].append(scene.scene_points[farthest_point_indices(scene.scene_points, n_s)])
    return {key: torch.from_numpy(np.stack(values)) for key, values in clouds.items()}


def recorded_policy(config: TaxDPDConfig) -> TaxDPDPolicy:
    """The policy in training mode as `lerobot-train` makes it on one of the project's datasets, which record
    their clouds in FPS order (the dataset's metadata says so, and the step skips FPS for the layouts)."""
    policy = TaxDPDPolicy(config).train()
    policy.training_clouds_fps_ordered = (True, True)
    return policy


def stage_of(module_name: str, module: torch.nn.Module) -> str | None:
    for stage, kind in STAGES.items():
        if (isinstance(kind, str) and module_name.endswith(kind)) or (
            not isinstance(kind, str) and isinstance(module, kind)
        ):
            return stage
    return None


def label_stages(policy: TaxDPDPolicy, stack: ExitStack) -> None:
    """Profiler labels around each stage's forward, removed when `stack` closes (the outermost labelled
    scope takes the time: encoders inside the GMM count as GMM)."""
    for name, module in policy.model.named_modules():
        stage = stage_of(name, module)
        if stage is None:
            continue
        scopes: list = []

        def enter(_module, _inputs, stage=stage, scopes=scopes) -> None:
            scopes.append(record_function(f"stage:{stage}"))
            scopes[-1].__enter__()

        def leave(_module, _inputs, _output, scopes=scopes) -> None:
            scopes.pop().__exit__(None, None, None)

        stack.callback(module.register_forward_pre_hook(enter).remove)
        stack.callback(module.register_forward_hook(leave).remove)


def breakdown(step, repeats: int) -> dict[str, float]:
    """Seconds a step spends per stage (self time of labelled scopes; nested stages count once, outermost)."""
    if not torch.cuda.is_available():  # else the profiler's GPU query prints `gpuGetDeviceCount failed` on a CPU
        os.environ.setdefault("KINETO_LOG_LEVEL", "5")
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(repeats):
            step()
    totals: dict[str, float] = {}
    for event in prof.events():
        if event.name.startswith("stage:") or event.name in ("forward", "backward", "optimizer"):
            parent = event.cpu_parent
            while parent is not None and not parent.name.startswith("stage:"):
                parent = parent.cpu_parent
            if parent is None:  # outermost labelled scope
                totals[event.name] = totals.get(event.name, 0.0) + event.cpu_time_total / 1e6 / repeats
    inner = sum(v for k, v in totals.items() if k.startswith("stage:"))
    return {
        **{k.removeprefix("stage:"): v for k, v in totals.items() if k.startswith("stage:")},
        "other_forward": totals.get("forward", 0.0) - inner,
        "backward": totals.get("backward", 0.0),
        "optimizer": totals.get("optimizer", 0.0),
    }


def launch_figures(fields: dict, batch_size: int, cloud_sizes: tuple[int, int]) -> dict:
    """Launches and host syncs of one training step (after a first one) and of one K = 10 sampling call, on
    clouds of `cloud_sizes` (object, scene) points, as recorded."""
    torch.manual_seed(0)
    config = TaxDPDConfig.for_point_clouds(device="cpu", point_scale=66.0, **fields)
    policy = recorded_policy(config)
    optimizer = config.get_optimizer_preset().build(policy.get_optim_params())
    batch = slot_batch(batch_size, *cloud_sizes)

    def step(counter: LaunchCounter) -> None:
        with counter.stage("forward"):
            loss, _ = policy.forward(batch)
        with counter.stage("backward"):
            loss.backward()
        with counter.stage("optimizer"):
            torch.nn.utils.clip_grad_norm_(policy.parameters(), config.optimizer_grad_clip_norm, foreach=True)
            optimizer.step()
            optimizer.zero_grad()
        with counter.stage("update"):  # the weight average and the step's one read-back
            policy.update()

    def count(run, models: list[torch.nn.Module]) -> dict:
        counter = LaunchCounter()
        with device_code_paths(), ExitStack() as stack:
            for model in models:
                counter.label_modules(
                    {
                        "gmm": [m for name, m in model.named_modules() if name.endswith("global_stage")],
                        "encoders": [m for m in model.modules() if isinstance(m, STAGES["encoders"])],
                        "dit": [m for m in model.modules() if isinstance(m, DiT)],
                    },
                    stack,
                )
            with counter:
                run(counter)
        return counter.summary()

    step(LaunchCounter())  # the first step also reads the weight average's step count once
    training = count(step, [policy.model])
    policy.eval()
    obj, scene = batch[OBJECT_KEY][:1], batch[SCENE_KEY][:1]
    policy.sample_goals(obj, scene, 10)  # the first call also makes the bf16 copy of the weights under AMP
    sampling = count(lambda _: policy.sample_goals(obj, scene, 10), [policy._sampling_model()])
    return {"training_step": training, "sample_k10": sampling}


def flops(run) -> float:
    """Matmul FLOPs of one call, attention on the math backend (the counter has no CPU flash formula)."""
    with sdpa_kernel(SDPBackend.MATH), FlopCounterMode(display=False) as counter:
        run()
    return float(counter.get_total_flops())


def policy_figures(fields: dict, args, cloud_sizes: tuple[int, int]) -> dict:
    """Step and sampling times in the policy on clouds of `cloud_sizes` points (object, scene), as recorded."""
    torch.manual_seed(0)
    config = TaxDPDConfig.for_point_clouds(device="cpu", point_scale=66.0, **fields)
    policy = recorded_policy(config)
    optimizer = config.get_optimizer_preset().build(policy.get_optim_params())
    batch = slot_batch(args.batch_size, *cloud_sizes)

    def step() -> None:
        with record_function("forward"):
            loss, _ = policy.forward(batch)
        with record_function("backward"):
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
        with record_function("optimizer"):
            torch.nn.utils.clip_grad_norm_(policy.parameters(), config.optimizer_grad_clip_norm)
            optimizer.step()
            policy.update()  # the weight average, when the recipe keeps one, as lerobot-train calls it

    step_s, step_times = timed(step, args.repeats)
    gflop = flops(step) / args.batch_size / 1e9
    with ExitStack() as stack:
        label_stages(policy, stack)
        stages = breakdown(step, max(2, args.repeats // 2))
    policy.eval()
    obj, scene = batch[OBJECT_KEY][:1], batch[SCENE_KEY][:1]
    sampling = {}
    for k in (1, 10):
        latency, times = timed(lambda k=k: policy.sample_goals(obj, scene, k), args.repeats)
        sampling[f"K={k}"] = {"latency_s": latency, "all_s": times}
    return {
        "step_s": step_s,
        "all_step_s": step_times,
        "samples_per_s": args.batch_size / step_s,
        "gflop_per_sample": gflop,
        "achieved_gflops": gflop * args.batch_size / step_s,
        "stages_s": stages,
        "sampling": sampling,
    }


def lerobot_train_figures(fields: dict, args, cloud_sizes: tuple[int, int]) -> dict:
    """Steps of `lerobot-train` on `--dataset`, or on a slot dataset with clouds of `cloud_sizes` points (object,
    scene); update and data times from its log."""
    with tempfile.TemporaryDirectory() as tmp:
        if args.dataset:
            root = args.dataset.resolve()
        else:
            root = Path(tmp) / "data"
            write_slot_dataset(
                root,
                episodes=32,
                object_cloud_size=cloud_sizes[0],
                scene_cloud_size=cloud_sizes[1],
                seed=0,
            )
        steps = args.train_steps
        command = [
            sys.executable,
            "-m",
            "lerobot.scripts.lerobot_train",
            "--policy.type=taxdpd",
            "--dataset.repo_id=local/speed",
            f"--dataset.root={root}",
            "--policy.push_to_hub=false",
            "--policy.device=cpu",
            *(f"--policy.{k}={json.dumps(v) if isinstance(v, list) else v}" for k, v in fields.items()),
            f"--batch_size={args.batch_size}",
            f"--steps={steps}",
            f"--log_freq={steps // 2}",
            f"--save_freq={10 * steps}",
            f"--num_workers={args.num_workers}",
            f"--output_dir={Path(tmp) / 'run'}",
        ]
        started = time.perf_counter()
        finished = subprocess.run(command, capture_output=True, text=True, check=True)
        wall = time.perf_counter() - started
    logged = re.findall(r"updt_s:([\d.]+) data_s:([\d.]+)", finished.stdout + finished.stderr)
    if not logged:
        raise RuntimeError("lerobot-train's log has no updt_s/data_s line")
    update_s, data_s = (float(x) for x in logged[-1])  # the second half of the run: past the warm-up
    return {
        "steps": steps,
        "update_s": update_s,
        "data_s": data_s,
        "step_s": update_s + data_s,
        "steps_per_s": 1.0 / (update_s + data_s),
        "wall_s_with_startup": wall,
        "num_workers": args.num_workers,
        "dataset": str(args.dataset or f"synthetic two-slot demos, {cloud_sizes[0]} / {cloud_sizes[1]} points"),
    }


def parse_overrides(tokens: list[str]) -> dict:
    values = {}
    for token in tokens:
        key, _, text = token.partition("=")
        try:
            values[key] = json.loads(text)
        except json.JSONDecodeError:
            values[key] = text
    return values


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", default="cpu,paper", help="cpu (the shipped CPU recipe) and/or paper")
    add_policy_overrides_argument(parser, "TaxDPDConfig overrides")
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--train-steps", type=int, default=40, help="lerobot-train steps timed (0: skip)")
    parser.add_argument("--num-workers", type=int, default=0, help="lerobot-train data workers")
    parser.add_argument(
        "--dataset", type=Path, default=None, help="a task's demonstrations for the lerobot-train figure"
    )
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--output", default="results/speed.json")
    parser.add_argument(
        "--launches-only", action="store_true", help="count launches and syncs only (no timing: any machine, any load)"
    )
    args = parser.parse_args()
    if args.dataset and not (args.dataset / "meta" / "info.json").is_file():
        parser.error(f"--dataset {args.dataset}: not a LeRobot dataset (no meta/info.json)")
    torch.set_num_threads(args.threads)
    overrides = parse_overrides(args.set)

    peak = {}
    if not args.launches_only:
        peak = {
            "fp32": matmul_gflops(torch.float32, 2048, args.repeats),
            "bf16": matmul_gflops(torch.bfloat16, 2048, args.repeats),
        }
    machine = machine_info()
    print(
        f"machine: {machine['cpu']} | {machine['cpu_count']} cores | torch {machine['torch']} | "
        f"{machine['torch_threads']} threads | load {machine['load_average_1min']:.1f}"
    )
    if peak:
        print(f"matmul peak (2048^3): fp32 {peak['fp32']:.0f} GFLOP/s, bf16 {peak['bf16']:.0f} GFLOP/s")
    results = []
    for name in args.models.split(","):
        fields = model_config(name, overrides)
        network = (fields["num_object_points"], fields["num_scene_points"])
        recorded = tuple(max(a, b) for a, b in zip(RECORDED_POINTS.get(name, network), network, strict=True))
        launches = launch_figures(fields, args.batch_size, recorded)
        row = {"model": name, "config": fields, "recorded_points": recorded, "launches": launches}
        results.append(row)
        print(f"{name} {json.dumps(fields)}")
        print(f"  clouds as recorded: {recorded[0]} / {recorded[1]} points (object / scene)")
        for what, counted in row["launches"].items():
            stages = ", ".join(f"{k} {v}" for k, v in counted["ops_by_stage"].items())
            print(f"  launches, {what}: {counted['ops']} ops, {counted['syncs']} host syncs ({stages})")
        if args.launches_only:
            continue
        row["policy"] = policy_figures(fields, args, recorded)
        p = row["policy"]
        precision = "bf16" if fields.get("use_amp") else "fp32"
        p["fraction_of_peak"] = p["achieved_gflops"] / peak[precision]
        if args.train_steps:
            row["lerobot_train"] = lerobot_train_figures(fields, args, recorded)
        stages = ", ".join(f"{k} {1000 * v:.0f}" for k, v in p["stages_s"].items())
        print(
            f"  policy step {p['step_s']:.3f} s ({p['samples_per_s']:.1f} samples/s, "
            f"{p['gflop_per_sample']:.2f} GFLOP/sample, {p['achieved_gflops']:.0f} GFLOP/s = "
            f"{100 * p['fraction_of_peak']:.0f}% of the {precision} peak)"
        )
        print(f"  stages (ms): {stages}")
        if "lerobot_train" in row:
            t = row["lerobot_train"]
            print(
                f"  lerobot-train: {t['step_s']:.3f} s/step ({t['steps_per_s']:.2f} steps/s; "
                f"update {t['update_s']:.3f} s, data {t['data_s']:.3f} s, {t['num_workers']} workers; "
                f"{t['dataset']})"
            )
        print(
            f"  sampling: K=1 {p['sampling']['K=1']['latency_s']:.3f} s, "
            f"K=10 {p['sampling']['K=10']['latency_s']:.3f} s"
        )
    path = write_json(
        args.output,
        {
            "machine": machine,
            "matmul_peak_gflops": peak,
            "arguments": vars(args),
            "reference_authors_code": REFERENCE,
            "results": results,
        },
    )
    print(f"wrote {path} (medians of {args.repeats}; the authors' code on this CPU: {REFERENCE})")


if __name__ == "__main__":
    main()
