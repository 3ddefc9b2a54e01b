"""`taxdpd-convert` / `python -m datasets_conv`: raw demos -> LeRobot v3.0 dataset on disk, optionally on the Hub."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from lerobot_taxdpd.cli_options import add_deprecated_alias
from lerobot_taxdpd.threads import add_threads_argument, configure_threads

PROG = "taxdpd-convert"

DESCRIPTION = """\
Convert robot demonstrations into a LeRobot v3.0 dataset for TAX-DPD (float32 point clouds, one demo = one
episode of several farthest-point samplings), write it to --root, and optionally push it to the Hugging Face
Hub. Pick the source format with the first argument; `%(prog)s SOURCE --help` describes its layout.
No data at hand? `%(prog)s samples --out DIR` writes a few raw demos of every layout and prints the command
that converts each.
"""

EPILOG = """\
examples:
  %(prog)s samples --out raw_samples
  %(prog)s rpdiff --raw-dir task_demos/mug_rack_easy_single/task_name_mug_on_rack \\
      --repo-id me/rpdiff_mug_easyrack --root data/rpdiff_mug_easyrack --split train
  %(prog)s dedo --kind goal --raw-dir cloth_dataset --repo-id me/dedo_cloth_goals --split train
  %(prog)s dedo --kind policy --raw-dir cloth_dataset --repo-id me/dedo_cloth_rollouts --split train
  %(prog)s nist --raw-dir nist_demos --repo-id me/nist_connectors --split train --units auto
  %(prog)s push --root data/rpdiff_mug_easyrack --repo-id me/rpdiff_mug_easyrack

A bad demo stops the run with an error naming the file and the field, and nothing is written; add
--skip-invalid to convert the rest and list the skipped demos in the summary and the dataset card.
To push, log in first (`hf auth login`, or set HF_TOKEN), then add --push [--private].
"""

SOURCE_HELP = {
    "rpdiff": (
        "RPDiff demo_aug_*.npz (per demo or chunked)",
        """\
--raw-dir is an RPDiff task folder, `<task>/<task_type>` (or `<task>` holding one `task_name_*` folder):
  demo_aug_<i>.npz                    one demo per file, or
  <k>/demo_aug_<j>.npz                chunked: keys "0".."9" each hold a whole demo
  split_info/{train_split,train_val_split,test_split}.txt   --split train/val/test
The task is read from the folder name; the paper's five tasks (mug_rack_easy_single, mug_rack_med_single,
mug_rack_med_multi, book_on_bookshelf_double_view_rnd_ori, can_in_cabinet_stack) get their point counts
from the paper (512/512, 512/512, 512/1024, 512/1024, 256/1024). Units: metres, world frame.

WARNING: RPDiff stores dicts as pickled object arrays, and unpickling can execute code. This converter
unpickles them (the format needs it): only convert files from a source you trust.""",
    ),
    "dedo": (
        "DEDO/TAX3D cloth goal demos (demo_*.npz) or policy rollouts (zarr)",
        """\
--raw-dir is a TAX3D cloth dataset folder:
  {train,val,val_ood}_tax3d/demo_<i>.npz   --kind goal: action_pc, anchor_pc, flow (goal = action_pc + flow)
  {train,val,val_ood}.zarr                 --kind policy: DP3 zarr rollouts for the gc_dp3 policy
--split test selects val_ood. A folder of demo_*.npz or a single .zarr store works with --split all.
Only the true cloth vertices (data/cloth) are sampled, never the zero padding. --kind policy writes one
frame per step (--frames-per-episode does not apply). Units: DEDO simulation units, as in the source. No
pickled field is read.""",
    ),
    "nist": (
        "NIST task-board connector demos (.npz, or teach data .ply + .npy)",
        """\
--raw-dir holds one folder per connector (or is one connector's folder); the folder name is the
connector type and becomes the task string:
  <connector>/{train,test}/*.npz or <connector>/*.npz   action_init_points, anchor_points, goal_tf
  <connector>/<demo>/{action.ply, anchor.ply, goal_tf.npy}   raw teach data (read with open3d)
goal_tf maps the goal onto the initial plug points (initial = goal_tf @ goal, column vectors), so the
goal is inverse(goal_tf) applied to the plug. Without train/test folders, --seed draws the held-out
demos per connector (--holdout-fraction, 4 of 20 as in the paper); --split val and test both select
them. --units auto reads a demo whose clouds span more than 5 units as millimetres.""",
    ),
}


def _common_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--raw-dir", type=Path, required=True, help="folder of raw demos (layout above)")
    parser.add_argument("--repo-id", required=True, help="dataset name on the Hub, e.g. 'me/rpdiff_mug_easyrack'")
    parser.add_argument("--root", type=Path, help="output folder; must not exist (default: $HF_LEROBOT_HOME/<repo-id>)")
    parser.add_argument(
        "--object-cloud-size",
        type=int,
        help="object points stored per frame (default: the task's; the network sees --policy.num_object_points)",
    )
    parser.add_argument("--scene-cloud-size", type=int, help="scene points stored per frame (default: the task's)")
    parser.add_argument("--split", choices=("train", "val", "test", "all"), default="all", help="default: all")
    parser.add_argument(
        "--frames-per-episode", type=int, default=2, help="independent samplings per demo (>= 2; default: 2)"
    )
    add_deprecated_alias(parser, "--frames-per-demo", "--frames-per-episode", "frames_per_episode", type=int)
    parser.add_argument("--seed", type=int, default=0, help="seed of the samplings (and NIST's split); default: 0")
    parser.add_argument("--task", help="override the plain-language task string")
    parser.add_argument("--skip-invalid", action="store_true", help="skip bad demos instead of stopping")
    parser.add_argument("--overwrite", action="store_true", help="replace --root once the new dataset is complete")
    parser.add_argument(
        "--license", dest="hub_license", metavar="LICENSE", help="licence tag of the Hub card (default: other)"
    )
    add_threads_argument(parser)
    _push_arguments(parser, optional=True)


def _push_arguments(parser: argparse.ArgumentParser, *, optional: bool) -> None:
    if optional:
        parser.add_argument("--push", action="store_true", help="upload to the Hub after converting")
    parser.add_argument("--private", action="store_true", help="create the Hub repository as private")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, description=DESCRIPTION, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sources = parser.add_subparsers(dest="source", required=True, metavar="{rpdiff,dedo,nist,push,samples}")
    for name, (summary, layout) in SOURCE_HELP.items():
        sub = sources.add_parser(
            name, help=summary, description=layout, formatter_class=argparse.RawDescriptionHelpFormatter
        )
        _common_arguments(sub)
        if name == "dedo":
            sub.add_argument("--kind", choices=("goal", "policy"), default="goal", help="default: goal")
            sub.add_argument("--fps", type=int, default=10, help="--kind policy: frame rate written (default: 10)")
            sub.add_argument(
                "--successful-demos",
                action="store_true",
                help="--kind policy: mark every rollout's last step as a success (the zarr does not say)",
            )
        if name == "nist":
            sub.add_argument(
                "--units", choices=("auto", "m", "mm"), default="auto", help="source units (default: auto)"
            )
            sub.add_argument(
                "--holdout-fraction", type=float, default=0.2, help="held-out share without train/test folders"
            )
    push = sources.add_parser("push", help="upload a converted dataset to the Hub")
    push.add_argument("--root", type=Path, required=True, help="folder of a dataset written by this tool")
    push.add_argument("--repo-id", required=True, help="dataset name on the Hub")
    _push_arguments(push, optional=False)
    samples = sources.add_parser(
        "samples",
        help="write a few raw demos of every layout, to try the converters without the real data",
        description="Write synthetic raw demos in every layout the converters read (RPDiff per demo and chunked, "
        "DEDO goal demos and zarr rollouts, NIST .npz and millimetre teach data) under --out, and print the "
        "command that converts each folder.",
    )
    samples.add_argument("--out", type=Path, required=True, help="folder to write; must not exist or be empty")
    samples.add_argument("--demos", type=int, default=4, help="demos of each layout (>= 2; default: 4)")
    samples.add_argument("--seed", type=int, default=0, help="seed of the synthetic clouds; default: 0")
    return parser


def _samples(out: Path, demos: int, seed: int) -> int:
    """Write the sample folders; refuse a non-empty --out, whose other files a converter would read too."""
    from datasets_conv.samples import conversion_commands, write_samples

    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        print(f"error: --out {out} exists and is not an empty folder: remove it or name another", file=sys.stderr)
        return 1
    try:
        write_samples(out, demos=demos, seed=seed)
    except ValueError as exc:
        print(f"error: --{exc}", file=sys.stderr)
        return 1
    commands = "\n".join(f"  {shlex.join([PROG, *argv])}" for argv in conversion_commands(out))
    print(f"wrote {demos} synthetic demos of every raw layout under {out}; convert each with:\n{commands}")
    return 0


def _convert(args: argparse.Namespace, root: Path, command: str):
    from datasets_conv.dedo import convert_dedo_goals, convert_dedo_rollouts
    from datasets_conv.nist import convert_nist
    from datasets_conv.pipeline import ConversionOptions
    from datasets_conv.rpdiff import convert_rpdiff

    options = ConversionOptions(
        object_cloud_size=args.object_cloud_size,
        scene_cloud_size=args.scene_cloud_size,
        frames_per_episode=args.frames_per_episode,
        split=args.split,
        seed=args.seed,
        skip_invalid=args.skip_invalid,
        overwrite=args.overwrite,
        hub_license=args.hub_license,
        task=args.task,
        command=command,
    )
    if args.source == "rpdiff":
        return convert_rpdiff(args.raw_dir, args.repo_id, root, options)
    if args.source == "nist":
        return convert_nist(
            args.raw_dir, args.repo_id, root, options, units=args.units, holdout_fraction=args.holdout_fraction
        )
    if args.kind == "goal":
        return convert_dedo_goals(args.raw_dir, args.repo_id, root, options)
    return convert_dedo_rollouts(
        args.raw_dir, args.repo_id, root, options, fps=args.fps, successful=args.successful_demos
    )


def _push_advice(error: Exception) -> str:
    """What to fix before retrying a push, from its cause: saying "log in" when the network is down sends a
    user after the wrong problem."""
    import requests
    from huggingface_hub.errors import HfHubHTTPError, LocalTokenNotFoundError, OfflineModeIsEnabled

    if isinstance(error, OfflineModeIsEnabled):
        return "HF_HUB_OFFLINE is set, so huggingface_hub does not contact the Hub: unset it once online"
    if isinstance(error, requests.ConnectionError | requests.Timeout):
        return "The Hub could not be reached (no network, or a proxy in the way): connect"
    status = getattr(getattr(error, "response", None), "status_code", None)
    if isinstance(error, LocalTokenNotFoundError) or (isinstance(error, HfHubHTTPError) and status in (401, 403)):
        return "Log in with write access (`hf auth login` or HF_TOKEN)"
    return "Fix the cause above"


def _push(root: Path, repo_id: str, private: bool) -> int:
    from lerobot_taxdpd.data.dataset_writer import push_dataset

    try:
        push_dataset(root, repo_id, private=private)
    except Exception as exc:  # noqa: BLE001 - any Hub/network failure leaves the local dataset intact
        print(
            f"error: pushing {root} to the Hub as {repo_id} failed ({type(exc).__name__}: {exc}).\n"
            f"The dataset on disk is complete. {_push_advice(exc)}, then retry with:\n"
            f"  {PROG} push --root {shlex.quote(str(root))} --repo-id {repo_id}" + (" --private" if private else ""),
            file=sys.stderr,
        )
        return 1
    print(f"pushed {root} to https://huggingface.co/datasets/{repo_id}")
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.source == "push":
        return _push(args.root, args.repo_id, args.private)
    if args.source == "samples":
        return _samples(args.out, args.demos, args.seed)
    if args.private and not args.push:
        parser.error("--private only applies with --push")

    # Heavy imports (LeRobot, torch) only once the arguments are known, so --help answers at once.
    from lerobot.utils.constants import HF_LEROBOT_HOME

    from datasets_conv.raw_io import DemoError, LayoutError
    from lerobot_taxdpd.data.validation import PointCloudError

    configure_threads(args.threads)
    root = args.root if args.root is not None else HF_LEROBOT_HOME / args.repo_id
    try:
        summary = _convert(args, root, shlex.join([PROG, *argv]))
    except (FileExistsError, FileNotFoundError, ValueError) as exc:  # DemoError, PointCloudError, bad options
        bad_demo = isinstance(exc, (DemoError, PointCloudError)) and not isinstance(exc, LayoutError)
        hint = "\n(nothing was written; --skip-invalid converts the other demos and lists this one)"
        print(f"error: {exc}" + (hint if bad_demo and not args.skip_invalid else ""), file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"interrupted: nothing was written, {root} is as it was", file=sys.stderr)
        return 130
    print(summary)
    return _push(summary.output, args.repo_id, args.private) if args.push else 0


if __name__ == "__main__":
    sys.exit(main())
