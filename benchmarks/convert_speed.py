"""How fast the converters are: farthest-point-sampling options on raw-size clouds, and RPDiff demos per second.

Converting is dominated by downsampling raw clouds of 30-60k points, so this times the FPS implementations
one could use (fpsample's bucketed KD-line FPS, which the converters use; fpsample's plain FPS; open3d; the
batched torch FPS of `lerobot_taxdpd.maths.geometry`) and then whole conversions of RPDiff-size demos (child 30k,
parent 60k points, 512/1024 sampled, 2 samplings per demo). Demo files are written with the test suite's
RPDiff fixture writer. Prints the machine, thread count and configuration beside the medians and writes
everything as JSON.

    python benchmarks/convert_speed.py                    # results/convert_speed.json
    python benchmarks/convert_speed.py --repeats 7 --demos 20 --threads 1
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def _median_ms(run, repeats: int) -> tuple[float, list[float]]:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        run()
        times.append((time.perf_counter() - started) * 1e3)
    return statistics.median(times), times


def fps_options(points: np.ndarray, num_samples: int, repeats: int) -> list[dict]:
    """Median latency of each FPS option, and whether its picks are exact FPS (torch's, from the same start)."""
    import fpsample
    import open3d as o3d
    import torch

    from lerobot_taxdpd.maths.geometry import farthest_point_indices, farthest_point_sample

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    tensor = torch.from_numpy(points)[None]
    options = {
        "fpsample.bucket_fps_kdline (converters)": lambda: points[farthest_point_indices(points, num_samples)],
        "fpsample.fps_sampling (plain)": lambda: points[fpsample.fps_sampling(points, num_samples, start_idx=0)],
        "open3d farthest_point_down_sample": lambda: np.asarray(cloud.farthest_point_down_sample(num_samples).points),
        "torch farthest_point_sample (geometry)": lambda: points[farthest_point_sample(tensor, num_samples)[0].numpy()],
    }
    rows = []
    for name, sample in options.items():
        chosen = sample()
        start = torch.tensor([int(np.flatnonzero((points == chosen[0]).all(1))[0])])
        exact = points[farthest_point_sample(tensor, num_samples, start_index=start)[0].numpy()]
        median, times = _median_ms(sample, repeats)
        same = {tuple(p) for p in chosen} == {tuple(p) for p in exact}
        rows.append({"option": name, "median_ms": median, "runs_ms": times, "exact_fps": same})
    rows[2]["note"] = "returns points, not indices: keeping goal rows paired needs an extra lookup"
    return rows


def conversion_rate(num_demos: int, repeats: int, workdir: Path) -> dict:
    """Median demos/s of `convert_rpdiff` on RPDiff-size demos (imports and file writing of inputs excluded)."""
    from datasets_conv.pipeline import ConversionOptions
    from datasets_conv.rpdiff import convert_rpdiff
    from datasets_conv.samples import rpdiff_demo, save_rpdiff_demo

    demo_dir = workdir / "mug_rack_med_multi" / "task_name_mug_on_rack_multi"
    rng = np.random.default_rng(0)
    for i in range(num_demos):
        save_rpdiff_demo(demo_dir / f"demo_aug_{i}.npz", rpdiff_demo(rng, n_child=30_000, n_parent=60_000)[0])
    rates = []
    for r in range(repeats):
        summary = convert_rpdiff(demo_dir, f"bench/run{r}", workdir / f"out{r}", ConversionOptions())
        rates.append(summary.demos_read / summary.seconds)
    return {
        "demos_per_run": num_demos,
        "child_points": 30_000,
        "parent_points": 60_000,
        "sampled_object_scene_points": [512, 1024],
        "frames_per_episode": 2,
        "median_demos_per_s": statistics.median(rates),
        "runs_demos_per_s": rates,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5, help="runs per measurement; medians are reported")
    parser.add_argument("--demos", type=int, default=10, help="RPDiff-size demos per conversion run")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    parser.add_argument("--output", type=Path, default=REPO / "results" / "convert_speed.json")
    args = parser.parse_args()

    import fpsample  # noqa: F401  (loaded first, so the machine record names its version)
    import open3d  # noqa: F401
    import torch

    from lerobot_taxdpd.reports.benchmarking import machine_info, write_json

    if args.threads:
        torch.set_num_threads(args.threads)
    machine = machine_info()
    rng = np.random.default_rng(0)
    clouds = {"60k -> 1024 (RPDiff parent)": (60_000, 1024), "30k -> 512 (RPDiff child)": (30_000, 512)}
    fps = {
        label: fps_options((rng.normal(size=(n, 3)) * [0.1, 0.2, 0.05]).astype(np.float32), m, args.repeats)
        for label, (n, m) in clouds.items()
    }
    with tempfile.TemporaryDirectory(prefix="convert-speed-") as workdir:
        conversion = conversion_rate(args.demos, args.repeats, Path(workdir))
    report = {"machine": machine, "repeats": args.repeats, "fps": fps, "rpdiff_conversion": conversion}

    print(
        f"machine: {machine['cpu']}, {machine['cpu_count']} CPUs, torch threads {machine['torch_threads']}, "
        f"load average {machine['load_average_1min']:.1f} at start"
    )
    print(f"medians of {args.repeats} runs")
    for label, rows in fps.items():
        print(f"\nFPS {label}")
        for row in rows:
            exact = "exact FPS" if row["exact_fps"] else "NOT exact FPS"
            print(f"  {row['option']:<42} {row['median_ms']:9.1f} ms   ({exact})")
    print(
        f"\nRPDiff conversion, {conversion['child_points']}/{conversion['parent_points']}-point demos -> 512/1024, "
        f"2 frames each: {conversion['median_demos_per_s']:.2f} demos/s"
    )
    print(f"\nwrote {write_json(args.output, report)}")


if __name__ == "__main__":
    main()
