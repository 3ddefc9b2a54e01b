"""Command line of the procedural benchmarks: `python -m lerobot_taxdpd.sim {generate,eval,pretrain} --task T ...`

    generate  scripted demonstrations -> a LeRobot v3.0 goal-prediction dataset (cloth_hang: and/or the
              gc_dp3 policy dataset)
    eval      a goal predictor on held-out trials -> JSON report and PNG figures (cloth_hang: also the
              gc_dp3 executor, with predicted and/or ground-truth goals)
    pretrain  generate + lerobot-train + eval, then save the checkpoint with its metrics (a shipped predictor)

One vocabulary for every task: `--goal-policy.path` is a goal predictor (taxdpd), `--policy.path` an
executor (gc_dp3, cloth_hang only). Options that only one kind of task takes are listed under their own
heading of `--help`.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from lerobot_taxdpd.cli_options import add_deprecated_alias, add_search_arguments, with_search
from lerobot_taxdpd.data.schema import CLOTH_TASK
from lerobot_taxdpd.maths.selection import GOAL_SELECTIONS
from lerobot_taxdpd.policies.taxdpd.configuration_taxdpd import GMM_FRAMES, check_frame_temperature
from lerobot_taxdpd.sim.splits import SPLITS
from lerobot_taxdpd.threads import add_threads_argument, configure_threads

#: Where eval writes by default, per kind of task.
OUTPUT = {"rigid": Path("outputs/sim_eval"), CLOTH_TASK: Path("outputs/eval/cloth_hang")}
RIGID_ONLY = {
    "predictor": "--predictor",
    "placement_frames": "--placement-frames",
    "gmm_frames": "--goal-policy.gmm-frames",
    "frame_temperature": "--goal-policy.frame-temperature",
    "oracle_error_mm": "--oracle-error-mm",
    "oracle_error_deg": "--oracle-error-deg",
    "observed_scene_cloud_size": "--scene-cloud-size",
}
CLOTH_ONLY = {
    "dataset": "--dataset",
    "object_cloud_size": "--object-cloud-size",
    "workers": "--workers",
    "action_noise": "--action-noise",
    "ground_truth_goals": "--ground-truth-goals",
    "compared_selections": "--compare-selections",
    "goal_threshold": "--goal-threshold",
    "ship": "--ship",
}


def build_parser() -> argparse.ArgumentParser:
    from lerobot_taxdpd.sim.cloth.datasets import DATASET_KINDS
    from lerobot_taxdpd.sim.tasks import task_names

    tasks = [*task_names(), CLOTH_TASK]
    parser = argparse.ArgumentParser(
        prog="python -m lerobot_taxdpd.sim", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    verbs = parser.add_subparsers(dest="verb", required=True)

    generate = verbs.add_parser("generate", help="write scripted demonstrations as LeRobot datasets")
    generate.add_argument("--task", required=True, choices=tasks)
    generate.add_argument("--episodes", type=int, required=True, help="number of demonstrations (one episode each)")
    generate.add_argument("--split", choices=SPLITS, default="train", help="geometry split (default: train)")
    generate.add_argument("--repo-id", required=True, help="dataset repo id, e.g. me/mug_easyrack")
    generate.add_argument("--root", required=True, type=Path, help="output folder; must not exist unless --overwrite")
    generate.add_argument("--seed", type=int, default=0, help="episode i uses scene seed SEED + i (default: 0)")
    generate.add_argument(
        "--frames-per-episode",
        type=int,
        default=None,
        help="observations of each demonstration, >= 2 (default: 2; cloth_hang: 4 point samplings)",
    )
    add_deprecated_alias(generate, "--views", "--frames-per-episode", "frames_per_episode", type=int)
    generate.add_argument(
        "--scene-cloud-size",
        type=int,
        default=None,
        help="scene points stored per frame (default: the paper's count of the task, e.g. 1024 for book_shelf; "
        "cloth_hang: 512 hanger points); a denser recording gives --policy.local_scene_points a finer crop",
    )
    generate.add_argument("--overwrite", action="store_true", help="replace an existing dataset at --root, atomically")
    add_threads_argument(generate)
    cloth = generate.add_argument_group("cloth_hang only")
    cloth.add_argument(
        "--dataset",
        choices=DATASET_KINDS,
        default=None,
        help="which dataset(s) to write (default: both, to "
        "ROOT/goal and ROOT/policy, their repo ids suffixed _goal and _policy)",
    )
    cloth.add_argument(
        "--object-cloud-size", type=int, default=None, help="cloth points stored per frame (default: 512)"
    )
    cloth.add_argument("--workers", type=int, default=None, help="parallel simulation processes (default: 1)")
    cloth.add_argument(
        "--action-noise",
        type=float,
        default=None,
        help="DART: the expert's actions are executed with Gaussian noise of this std (metres a coordinate) "
        "while the dataset records the expert's own actions, so the policy sees recoveries (default: 0)",
    )

    evaluate = verbs.add_parser("eval", help="evaluate a goal predictor (cloth_hang: and an executor), held out")
    evaluate.add_argument("--task", required=True, choices=tasks)
    evaluate.add_argument(
        "--goal-policy.path",
        dest="goal_policy_path",
        metavar="NAME_OR_PATH",
        help="TAX-DPD goal predictor: a shipped name, a checkpoint folder or a Hub id",
    )
    evaluate.add_argument("--trials", type=int, default=100, help="number of trials (default: 100)")
    evaluate.add_argument("--num-samples", type=int, default=10, help="goals sampled per trial, K (default: 10)")
    evaluate.add_argument(
        "--goal-selection",
        choices=GOAL_SELECTIONS,
        default=None,
        help="which of the K samples is executed: the first (the paper's one shot), the one most other samples "
        "agree with, within the coverage threshold, or the one a learned scorer rates highest (--scorer.path) "
        "(default: scorer when --scorer.path is given; else first on rigid tasks, as in the paper, and consensus "
        "on cloth_hang, where it was measured better)",
    )
    evaluate.add_argument(
        "--scorer.path",
        dest="scorer_path",
        metavar="NAME_OR_PATH",
        help="goal scorer for --goal-selection scorer: a shipped name that has one (its scorer/), a folder "
        "written by `python -m lerobot_taxdpd.scoring train` or a Hub id",
    )
    add_search_arguments(evaluate, "--scorer.")
    evaluate.add_argument("--seed", type=int, default=0, help="trial i uses scene seed SEED + i (default: 0)")
    evaluate.add_argument("--split", choices=SPLITS, default="test", help="geometry split (default: test, held out)")
    evaluate.add_argument(
        "--output",
        type=Path,
        default=None,
        help="folder for the JSON and PNGs (default: outputs/sim_eval; cloth_hang: outputs/eval/cloth_hang)",
    )
    evaluate.add_argument("--figures", type=int, default=3, help="trials to draw as PNGs (default: 3)")
    add_deprecated_alias(evaluate, "--plots", "--figures", "figures", type=int)
    evaluate.add_argument("--device", default="cpu", help="where the policies run: cpu, cuda, ... (default: cpu)")
    add_threads_argument(evaluate)
    rigid = evaluate.add_argument_group("rigid tasks only")
    rigid.add_argument(
        "--predictor",
        help="instead of --goal-policy.path: 'oracle' (ground truth, checks the benchmark itself) or "
        "'package.module:factory' returning an object with sample_goals(object_points, scene_points, num_samples)",
    )
    rigid.add_argument(
        "--placement-frames",
        choices=("true",),
        default=None,
        help="--goal-policy.path only: 'true' samples every goal at the true placement frame (the demonstrated "
        "goal's centroid) instead of the Dense GMM's, to measure the local stage alone (default: the GMM's)",
    )
    rigid.add_argument(
        "--goal-policy.gmm-frames",
        dest="gmm_frames",
        choices=GMM_FRAMES,
        default=None,
        help="--goal-policy.path only: how the Dense GMM's frames are drawn, at a component's mean (as published) "
        "or moved to the peak of the mixture's density it lies under (default: the checkpoint's gmm_frames)",
    )
    rigid.add_argument(
        "--goal-policy.frame-temperature",
        dest="frame_temperature",
        type=float,
        default=None,
        metavar="TAU",
        help="--goal-policy.path only: the scale of the placement frame's starting noise while sampling, 1 as "
        "published, 0 starts every sample at its GMM frame (default: the checkpoint's frame_temperature)",
    )
    rigid.add_argument(
        "--scene-cloud-size",
        dest="observed_scene_cloud_size",
        type=int,
        default=None,
        help="scene points observed per trial (default: what --goal-policy.path was trained on, else the task's)",
    )
    rigid.add_argument("--oracle-error-mm", type=float, default=None, help="oracle only: translation error to add")
    rigid.add_argument("--oracle-error-deg", type=float, default=None, help="oracle only: rotation error to add")
    cloth = evaluate.add_argument_group("cloth_hang only")
    cloth.add_argument(
        "--policy.path",
        dest="policy_path",
        metavar="PATH",
        help="gc_dp3 executor: a shipped name (cloth_hang), a pretrained_model folder or a Hub id; with "
        "--goal-policy.path it executes one predicted goal (--goal-selection)",
    )
    cloth.add_argument(
        "--ground-truth-goals", action="store_true", default=None, help="also execute a ground-truth goal"
    )
    cloth.add_argument(
        "--compare-selections",
        dest="compared_selections",
        nargs="+",
        choices=GOAL_SELECTIONS,
        default=None,
        metavar="RULE",
        help="also execute the samples these rules choose (first, consensus, scorer), on the same samples of "
        "each trial: success beside --goal-selection's, with paired counts (a rule that chooses the same sample "
        "shares its rollout)",
    )
    cloth.add_argument(
        "--goal-threshold", type=float, default=None, help="RMSE for coverage@K / precision@K (default: 0.5)"
    )
    cloth.add_argument("--workers", type=int, default=None, help="parallel simulation processes (default: 1)")
    cloth.add_argument(
        "--ship",
        type=Path,
        default=None,
        help="save the goal predictor as <SHIP>/cloth_hang and the executor as "
        "<SHIP>/cloth_hang/executor, each with these results",
    )

    pretrain = verbs.add_parser(
        "pretrain",
        help="demos, lerobot-train, held-out eval, and a packaged checkpoint",
        epilog="Any --policy.<field>=<value> flag (e.g. --policy.use_gmm=false) and --seed=<n> are passed on "
        "to lerobot-train.",
    )
    pretrain.add_argument("--task", required=True, choices=task_names())
    pretrain.add_argument("--episodes", type=int, default=200, help="training demonstrations (default: 200)")
    pretrain.add_argument("--steps", type=int, default=None, help="training steps (default: the config's)")
    pretrain.add_argument(
        "--resume-steps",
        type=int,
        default=None,
        help="then train on to this many steps in a second leg (lerobot-train --resume=true): a long recipe in "
        "legs that each fit a session; a rerun with the same flags goes on from the last checkpoint",
    )
    pretrain.add_argument(
        "--config", default=None, help="a shipped recipe name or a lerobot-train config file (default: taxdpd_cpu)"
    )
    pretrain.add_argument("--trials", type=int, default=100, help="held-out evaluation trials (default: 100)")
    pretrain.add_argument("--num-samples", type=int, default=10, help="goals sampled per trial, K (default: 10)")
    pretrain.add_argument("--output", type=Path, default=None, help="work folder (default: results/pretrain/<task>)")
    pretrain.add_argument("--ship", type=Path, default=None, help="save the evaluated checkpoint as <SHIP>/<task>")
    pretrain.add_argument(
        "--dataset",
        type=Path,
        default=None,
        help="demonstrations folder, generated if missing (default: <output>/data)",
    )
    pretrain.add_argument(
        "--overwrite",
        action="store_true",
        help="make new demonstrations and retrain, replacing those in place (default: reuse them only when made "
        "with the same options and training command, refuse otherwise)",
    )
    pretrain.add_argument(
        "--scene-cloud-size",
        type=int,
        default=None,
        help="scene points recorded per demonstration and observed per held-out trial (default: the task's)",
    )
    pretrain.add_argument(
        "--init-from",
        metavar="NAME_OR_PATH",
        default=None,
        help="fine-tune: start from this goal predictor's weights (a shipped name, a checkpoint folder or a Hub "
        "id) instead of random ones; its own policy config (architecture, learning rate, warm-up) replaces the "
        "recipe's, with the recipe's weight average put back on; the recipe's steps and batch still apply, and "
        "--policy.<field> flags win (e.g. a smaller --policy.optimizer_lr)",
    )
    add_threads_argument(pretrain)
    return parser


def _refuse_other_kinds_options(args: argparse.Namespace) -> None:
    """Options of the other kind of task are an error, not silently ignored."""
    cloth = args.task == CLOTH_TASK
    for dest, flag in (RIGID_ONLY if cloth else CLOTH_ONLY).items():
        if getattr(args, dest, None) is not None:
            kind = "a rigid task" if cloth else "--task cloth_hang"
            raise ValueError(f"{flag}: only applies to {kind}, not to --task {args.task}")


def _pretrain(args: argparse.Namespace, overrides: list[str]) -> int:
    from lerobot_taxdpd.sim.pretrain import CPU_RECIPE, pretrain

    pretrain(
        args.task,
        args.output or Path("results/pretrain") / args.task,
        episodes=args.episodes,
        steps=args.steps,
        recipe=args.config or CPU_RECIPE,
        trials=args.trials,
        num_samples=args.num_samples,
        ship=args.ship,
        dataset=args.dataset,
        overrides=overrides,
        overwrite=args.overwrite,
        resume_steps=args.resume_steps,
        scene_cloud_size=args.scene_cloud_size,
        init_from=args.init_from,
    )
    return 0


def _generate(args: argparse.Namespace, command: str) -> int:
    if args.task == CLOTH_TASK:
        from lerobot_taxdpd.sim.cloth.datasets import generate

        summary = generate(
            split=args.split,
            seed=args.seed,
            episodes=args.episodes,
            root=args.root,
            repo_id=args.repo_id,
            workers=_workers(args),
            overwrite=args.overwrite,
            command=command,
            **_given(
                kind=args.dataset,
                frames_per_episode=args.frames_per_episode,
                object_cloud_size=args.object_cloud_size,
                scene_cloud_size=args.scene_cloud_size,
                action_noise=args.action_noise,
            ),
        )
        print(json.dumps(summary, indent=2))
        return 0
    from lerobot_taxdpd.sim.generate import generate_dataset
    from lerobot_taxdpd.sim.tasks import get_task

    root = generate_dataset(
        get_task(args.task).with_scene_cloud_size(args.scene_cloud_size),
        episodes=args.episodes,
        split=args.split,
        repo_id=args.repo_id,
        root=args.root,
        seed=args.seed,
        overwrite=args.overwrite,
        command=command,
        **_given(frames_per_episode=args.frames_per_episode),
    )
    print(f"wrote {args.episodes} {args.task} demonstrations ({args.split} geometry) to {root}")
    return 0


def _given(**options) -> dict:
    """The options the user gave (not None): the others keep the defaults of the function they go to."""
    return {name: value for name, value in options.items() if value is not None}


def _workers(args: argparse.Namespace) -> int:
    workers = 1 if args.workers is None else args.workers
    if workers < 1:
        raise ValueError(f"--workers: must be at least 1, got {workers}")
    return workers


def _evaluate_cloth(args: argparse.Namespace) -> int:
    from lerobot_taxdpd.sim.cloth.evaluation import (
        EVAL_FILE,
        SHIP_WITH_A_SCORER,
        evaluate,
        ship_pipeline,
        summary_line,
    )

    output = args.output or OUTPUT[CLOTH_TASK]
    selection, scorer_path, scorer = _scorer_selection(args, args.goal_policy_path)  # workers load it by its path
    if scorer is not None and scorer.config.search_extent_mm:
        raise ValueError(
            f"{CLOTH_TASK}: the scorer's search around its samples is for rigid tasks (a shifted cloth goal is not "
            "measured); give --scorer.search-extent-mm 0"
        )
    if args.ship is not None and selection == "scorer":
        raise ValueError(SHIP_WITH_A_SCORER)
    summary = evaluate(
        split=args.split,
        seed=args.seed,
        trials=args.trials,
        output=output,
        policy_path=args.policy_path,
        goal_policy_path=args.goal_policy_path,
        ground_truth_goals=bool(args.ground_truth_goals),
        num_goal_samples=args.num_samples,
        **_given(
            goal_threshold=args.goal_threshold,
            goal_selection=selection,
            compared_selections=args.compared_selections,
            scorer_path=scorer_path,
        ),
        figures=args.figures,
        workers=_workers(args),
        device=args.device,
    )
    print(summary_line(summary, output / EVAL_FILE))
    if args.ship is not None:
        print(f"shipped as {ship_pipeline(summary, args.ship)} (goal predictor and executor/)")
    return 0


def _goal_predictor_source(args: argparse.Namespace) -> str | None:
    """`--goal-policy.path`; on a rigid task, the old `--policy.path` spelling of it, with a warning."""
    if args.policy_path is None:
        return args.goal_policy_path
    if args.goal_policy_path is not None:
        raise ValueError("--policy.path: names a gc_dp3 executor, which only --task cloth_hang takes")
    print(
        "warning: --policy.path for a goal predictor is deprecated, use --goal-policy.path (--policy.path names "
        "the gc_dp3 executor of cloth_hang)",
        file=sys.stderr,
    )
    return args.policy_path


def _warn_if_trained_for_another_task(predictor, source: str, task: str) -> None:
    """A predictor evaluated on a task its card does not name runs, but the user should know why it fails."""
    trained_on = getattr(predictor, "metrics", {}).get("task")
    if trained_on and trained_on != task:
        print(
            f"warning: --goal-policy.path {source} was trained for {trained_on}, not for --task {task}; "
            "its results here measure transfer to another task",
            file=sys.stderr,
        )


def _scorer_selection(args: argparse.Namespace, goal_policy_path: str | None):
    """The selection rule, and the scorer's folder and the scorer loaded from it (None, None without one):
    `--scorer.path` implies `scorer`; `--goal-selection scorer` alone takes the scorer shipped with the goal
    predictor's name. Checked before any trial runs."""
    from lerobot_taxdpd.goal_predictors import load_scorer, resolve_scorer

    compared = args.compared_selections or ()
    selection = args.goal_selection or ("scorer" if args.scorer_path and "scorer" not in compared else None)
    if "scorer" not in (selection, *compared):
        if args.scorer_path:
            raise ValueError(f"--scorer.path: only used with --goal-selection scorer, not {selection}")
        return selection, None, None
    source = args.scorer_path or goal_policy_path
    if source is None:
        raise ValueError("goal selection scorer: give --scorer.path (the scorer of the goal predictor evaluated)")
    try:
        folder = resolve_scorer(source)
        scorer = load_scorer(folder)
    except (OSError, ValueError) as error:
        raise ValueError(f"--scorer.path {source}: {error}") from error
    _warn_if_scorer_learnt_another_predictor(folder, goal_policy_path)
    scorer.config = with_search(scorer.config, args)
    return selection, folder, scorer


def _warn_if_scorer_learnt_another_predictor(scorer_folder: str, goal_policy_path: str | None) -> None:
    """A scorer learns one predictor's mistakes: say so when the predictor evaluated is not the one whose samples
    it was trained on (compared by the hash of the weights, where both are folders here)."""
    from lerobot_taxdpd.data.schema import METRICS_FILE
    from lerobot_taxdpd.goal_predictors import resolve_goal_predictor, weights_digest

    metrics = Path(scorer_folder) / METRICS_FILE
    if goal_policy_path is None or not metrics.is_file():
        return
    trained_for = json.loads(metrics.read_text()).get("collection", {}).get("goal_policy_weights")
    evaluated = weights_digest(resolve_goal_predictor(goal_policy_path))
    if trained_for and evaluated != "unknown" and trained_for != evaluated:
        print(
            f"warning: --scorer.path {scorer_folder} was trained on the samples of another goal predictor than "
            f"{goal_policy_path} (weights {trained_for}, not {evaluated}); collect and train it again for this one",
            file=sys.stderr,
        )


def _check_device(device: str) -> None:
    """`--device cuda` on a machine without a GPU: say so, before loading a policy fails with another message."""
    import torch

    if device.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(f"--device {device}: torch sees no CUDA GPU on this machine; use --device cpu")


def _evaluate(args: argparse.Namespace) -> int:
    from lerobot_taxdpd.goal_predictors import load_goal_predictor
    from lerobot_taxdpd.reports.benchmarking import write_json
    from lerobot_taxdpd.sim.harness import evaluate
    from lerobot_taxdpd.sim.predictors import OraclePredictor, TrueFramePredictor, load_predictor, observed_as_trained
    from lerobot_taxdpd.sim.tasks import get_task
    from lerobot_taxdpd.sim.trials import make_trial

    if args.trials < 1:
        raise ValueError(f"--trials: must be at least 1, got {args.trials}")
    goal_policy_path = _goal_predictor_source(args)
    if (goal_policy_path is None) == (args.predictor is None):
        raise ValueError("--goal-policy.path or --predictor: give exactly one (the goal predictor to evaluate)")
    task = get_task(args.task)
    seeds = range(args.seed, args.seed + args.trials)
    oracle = args.predictor == "oracle"
    oracle_error_mm, oracle_error_deg = args.oracle_error_mm or 0.0, args.oracle_error_deg or 0.0
    if not oracle and (oracle_error_mm or oracle_error_deg):
        raise ValueError("--oracle-error-mm/--oracle-error-deg only apply to --predictor oracle")
    sampling_flags = (
        (args.placement_frames, "--placement-frames"),
        (args.gmm_frames, "--goal-policy.gmm-frames"),
        (args.frame_temperature, "--goal-policy.frame-temperature"),
    )
    for given, flag in sampling_flags:
        if given is not None and not goal_policy_path:
            raise ValueError(f"{flag}: only applies to a TAX-DPD goal predictor (--goal-policy.path)")
    if goal_policy_path:
        try:
            predictor = load_goal_predictor(goal_policy_path, device=args.device)
        except (OSError, ValueError) as error:
            raise ValueError(
                f"--goal-policy.path {goal_policy_path}: not a loadable TAX-DPD checkpoint ({error})"
            ) from error
        _warn_if_trained_for_another_task(predictor, goal_policy_path, task.name)
        if args.gmm_frames:
            predictor.config.gmm_frames = args.gmm_frames
        gmm_frames = predictor.config.gmm_frames
        if args.frame_temperature is not None:
            try:
                check_frame_temperature(args.frame_temperature, predictor.config.disentangled)
            except ValueError as error:
                raise ValueError(f"--goal-policy.frame-temperature {args.frame_temperature}: {error}") from error
            predictor.config.frame_temperature = args.frame_temperature
        frame_temperature = predictor.config.frame_temperature
    elif not oracle:
        predictor = load_predictor(args.predictor)
    if not oracle:  # a predictor with a policy's config states its scene size, whichever way it was given
        task = observed_as_trained(task, predictor)
    task = task.with_scene_cloud_size(args.observed_scene_cloud_size)
    trials = (make_trial(task, seed, args.split) for seed in seeds)
    if oracle or args.placement_frames:  # both answer from the trials' ground truth, so they need them first
        trials = list(trials)
    if oracle:
        predictor = OraclePredictor(trials, oracle_error_mm / 1000, oracle_error_deg, seed=args.seed)
    elif args.placement_frames:
        predictor = TrueFramePredictor(predictor, trials)
    output = args.output or OUTPUT["rigid"]
    selection, _, scorer = _scorer_selection(args, goal_policy_path)
    report = evaluate(
        predictor,
        trials,
        args.num_samples,
        **_given(goal_selection=selection),
        scorer=scorer,
        figures_dir=output / "figures",
        num_figures=args.figures,
        total=args.trials,
    )
    report["predictor"] = goal_policy_path or args.predictor
    report["scene_points"] = task.num_points[1]
    if scorer is not None:
        report["scorer"] = args.scorer_path or goal_policy_path
    if args.placement_frames:
        report["placement_frames"] = args.placement_frames
    if goal_policy_path:
        report["gmm_frames"] = gmm_frames
        report["frame_temperature"] = frame_temperature
    path = write_json(output / f"{task.name}_eval.json", report)
    s = report["success"]
    print(
        f"{task.name}: success {s['success_rate']:.1%} (95% CI {s['ci95_low']:.1%}-{s['ci95_high']:.1%}) over "
        f"{s['trials']} trials; median translation error {report['translation_error_mm']['median']:.2f} mm, "
        f"rotation error {report['rotation_error_deg']['median']:.2f} deg; report: {path}"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    overrides = [
        arg for arg in unknown if args.verb == "pretrain" and arg.startswith(("--policy.", "--seed=")) and "=" in arg
    ]
    if len(overrides) < len(unknown):
        parser.error(f"unrecognized arguments: {' '.join(arg for arg in unknown if arg not in overrides)}")
    configure_threads(args.threads)
    command = "python -m lerobot_taxdpd.sim " + shlex.join(argv)
    try:
        if args.verb == "pretrain":
            return _pretrain(args, overrides)
        _refuse_other_kinds_options(args)
        if args.verb == "generate":
            return _generate(args, command)
        _check_device(args.device)
        if args.task == CLOTH_TASK:
            return _evaluate_cloth(args)
        return _evaluate(args)
    except (ValueError, FileExistsError, FileNotFoundError, TypeError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
