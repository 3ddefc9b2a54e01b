"""Evaluation of the cloth-hanging pipeline on held-out scenes.

Per trial (one scene): the valid goals are found by running the expert for every (hole, hanger) (when
only the ground-truth run is asked for, until one succeeds); the goal predictor (a `taxdpd` checkpoint)
samples K goal clouds from the start cloth and the hangers, scored by coverage and precision against the
valid goals; the `gc_dp3` policy then hangs the cloth conditioned on one predicted goal (by default the one
the samples agree on, `maths.selection`; measured better here than the first, docs/cloth.md), and
separately on one ground-truth goal (an upper bound). Trials are independent and run in parallel
processes; each trial is seeded by its scene seed, so results do not depend on the number of workers.
"""

from __future__ import annotations

import functools
import json
import multiprocessing
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from lerobot_taxdpd.data.schema import CLOTH_TASK, GOAL_CLOUD_KEY
from lerobot_taxdpd.maths.metrics import (
    coverage_precision,
    coverage_precision_from_rmse,
    paired_outcomes,
    pairwise_rmse,
    success_summary,
)
from lerobot_taxdpd.maths.selection import check_goal_selection, executed_first
from lerobot_taxdpd.recipes import portable_train_command
from lerobot_taxdpd.reports.benchmarking import machine_info, write_json
from lerobot_taxdpd.reports.plots import plot_goal_samples
from lerobot_taxdpd.sim.cloth.env import TASK_DESCRIPTION, ClothHangEnv
from lerobot_taxdpd.sim.cloth.rollout import Controller, Episode, rollout, valid_goal_clouds
from lerobot_taxdpd.sim.cloth.scene import SPLITS, sample_scene

#: Why `--ship` takes no scorer's choice: the shipped pipeline must run with what it ships.
SHIP_WITH_A_SCORER = (
    "--ship: the pipeline ships with a rule that needs no scorer (--goal-selection consensus or first; compare "
    "the scorer with --compare-selections scorer); ship a scorer with python -m lerobot_taxdpd.scoring ship "
    "--task cloth_hang"
)

#: The report `evaluate` writes into its output folder, beside `figures/`.
EVAL_FILE = "cloth_hang_eval.json"


@dataclass(frozen=True)
class TrialRequest:
    split: str
    seed: int
    policy_path: str | None
    goal_policy_path: str | None
    ground_truth_goals: bool
    num_goal_samples: int
    goal_selection: str
    compared_selections: tuple[str, ...]
    goal_threshold: float
    scorer_path: str | None
    figure_dir: str | None
    device: str
    torch_threads: int


def load_gc_dp3(path: str, device: str = "cpu"):
    """The policy and its saved processors from a shipped name (`cloth_hang`), a checkpoint folder
    (`.../pretrained_model`) or a Hub repo id."""
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_taxdpd.goal_predictors import resolve_executor
    from lerobot_taxdpd.policies.gc_dp3.modeling_gc_dp3 import GcDp3Policy

    path = resolve_executor(path)
    policy = GcDp3Policy.from_pretrained(path)
    policy.config.device = device
    policy.to(device).eval()
    overrides = {"device_processor": {"device": device}}
    preprocessor, postprocessor = make_pre_post_processors(
        policy.config, pretrained_path=path, preprocessor_overrides=overrides
    )
    return policy, preprocessor, postprocessor


def policy_controller(policy, preprocessor, postprocessor, goal: np.ndarray) -> Callable[[ClothHangEnv], Controller]:
    """gc_dp3 as a controller: observation + the goal cloud -> gripper deltas."""
    goal_tensor = torch.from_numpy(np.asarray(goal, dtype=np.float32))

    def make(env: ClothHangEnv) -> Controller:
        policy.reset()

        def act(observation: dict[str, np.ndarray]) -> np.ndarray:
            batch = {key: torch.from_numpy(value) for key, value in observation.items()}
            batch[GOAL_CLOUD_KEY] = goal_tensor
            with torch.inference_mode():
                action = postprocessor(policy.select_action(preprocessor(batch)))
            return action.reshape(-1).cpu().numpy()

        return act

    return make


def run_trial(request: TrialRequest) -> dict:
    """One held-out scene: valid goals, goal-predictor metrics and policy rollouts."""
    torch.set_num_threads(request.torch_threads)
    started = time.perf_counter()
    env = ClothHangEnv(request.split)
    try:
        scene = sample_scene(request.split, request.seed, env.ranges)
        # Pairs in a random order fixed by the seed: the first valid one is the ground-truth goal. Without a
        # goal predictor to score, only that one goal is needed.
        rng = np.random.default_rng([SPLITS.index(request.split), request.seed, 4])
        pairs = [(h, j) for h in range(len(scene.holes)) for j in range(len(scene.hangers))]
        pairs = [pairs[i] for i in rng.permutation(len(pairs))]
        goal_clouds = valid_goal_clouds(env, scene, pairs, stop_after=None if request.goal_policy_path else 1)
        start_cloud, hanger_cloud = env.cloth_points(), env.hanger_points
        keys, goals = list(goal_clouds), list(goal_clouds.values())
        result: dict = {"seed": request.seed, "holes": len(scene.holes), "valid_goals": [list(k) for k in keys]}
        if not goals:
            result["seconds"] = time.perf_counter() - started
            return result
        executor = cached_executor(request.policy_path, request.device) if request.policy_path else None
        if request.ground_truth_goals and executor is not None:
            torch.manual_seed(request.seed)
            result["ground_truth_pair"] = list(keys[0])
            result["ground_truth_goal"] = _outcome(rollout(env, scene, policy_controller(*executor, goals[0])))
        predicted = None
        if request.goal_policy_path:
            predicted = sample_goals(
                request.goal_policy_path,
                start_cloud,
                hanger_cloud,
                request.num_goal_samples,
                request.seed,
                request.device,
            )
            valid = np.stack(goals)
            rmse = pairwise_rmse(predicted, valid)
            result["goal_metrics"] = coverage_precision_from_rmse(rmse, request.goal_threshold)
            # Each sample's RMSE to its nearest valid goal, in the order drawn: which rule would have picked a
            # valid goal can be read off any report.
            result["sample_goal_rmse"] = rmse.min(1).tolist()
            scores = None
            if request.scorer_path:
                scores = _scorer(request.scorer_path).score(
                    torch.from_numpy(predicted), torch.from_numpy(hanger_cloud), torch.from_numpy(start_cloud)
                )
                result["sample_scores"] = scores.tolist()
                scores = scores.numpy()
            samples = predicted
            predicted, result["executed_sample"] = executed_first(
                samples, request.goal_selection, request.goal_threshold, scores
            )
            # The trivial baseline beside it: the start cloth, unchanged in shape and orientation, moved to the
            # centroid of the ground-truth goal.
            copied = start_cloud - start_cloud.mean(0) + goals[0].mean(0)
            result["copy_start_goal_metrics"] = coverage_precision(
                copied[None], valid, request.goal_threshold
            )
            if executor is not None:
                hung: dict[int, dict] = {}  # sample index -> outcome: rules that choose alike share one rollout

                def hang(index: int) -> dict:
                    if index not in hung:
                        torch.manual_seed(request.seed)
                        hung[index] = _outcome(rollout(env, scene, policy_controller(*executor, samples[index])))
                    return hung[index]

                result["predicted_goal"] = hang(result["executed_sample"])
                for rule in request.compared_selections:
                    _, index = executed_first(samples, rule, request.goal_threshold, scores)
                    result.setdefault("compared_selections", {})[rule] = {
                        "executed_sample": index,
                        "predicted_goal": hang(index),
                    }
        if request.figure_dir:
            path = Path(request.figure_dir) / f"{request.split}_{request.seed:04d}.png"
            shown = predicted if predicted is not None else np.zeros((0, *start_cloud.shape))
            title = f"cloth_hang {request.split} seed {request.seed}: {len(goals)} valid goal{'s' * (len(goals) > 1)}"
            figure = plot_goal_samples(
                path,
                hanger_cloud,
                start_cloud,
                shown,
                valid_goals=goals,
                first_sample_label="executed by gc_dp3" if executor is not None else "",
                scene_label="hangers",
                object_label="cloth (start)",
                title=f"{title}, {len(shown)} predicted",
            )
            result["figure"] = str(figure)
        result["seconds"] = time.perf_counter() - started
        return result
    finally:
        env.close()


def _outcome(episode: Episode) -> dict:
    return {
        "success": episode.success,
        "hole_at_a_peg_before_release": bool(episode.pre_release.any()),
        "seconds": episode.seconds,
    }


@functools.lru_cache(maxsize=2)
def cached_executor(path: str, device: str):
    """The executor and its processors, loaded once per worker process (`policy_controller` resets it)."""
    return load_gc_dp3(path, device)


@functools.lru_cache(maxsize=2)
def _scorer(path: str):
    """The goal scorer, loaded once per worker process."""
    from lerobot_taxdpd.goal_predictors import load_scorer

    return load_scorer(path)


@functools.lru_cache(maxsize=2)
def _goal_predictor(path: str, device: str):
    """The goal predictor, loaded once per worker process (it keeps no state between calls)."""
    from lerobot_taxdpd.goal_predictors import load_goal_predictor

    return load_goal_predictor(path, device=device)


def sample_goals(
    path: str, cloth: np.ndarray, hangers: np.ndarray, num_samples: int, seed: int, device: str = "cpu"
) -> np.ndarray:
    """K goal clouds (K, N, 3) from a `taxdpd` goal predictor (shipped name, folder or Hub id) for one scene,
    drawn from their own generator so a trial's goals do not depend on what ran before it in the worker."""
    with torch.inference_mode():
        samples = _goal_predictor(path, device).sample_goals(
            torch.from_numpy(cloth).float()[None], torch.from_numpy(hangers).float()[None], num_samples,
            generator=torch.Generator().manual_seed(seed),
        )
    return samples[0].cpu().numpy().astype(np.float64)


def run_trials(requests: list[TrialRequest], workers: int) -> Iterator[dict]:
    if workers <= 1:
        yield from map(run_trial, requests)
        return
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        yield from pool.map(run_trial, requests)


def summarise(trials: list[dict], config: dict, workers: int) -> dict:
    """Success rates with Wilson intervals, goal metrics and timings, with the machine (and its load) beside them."""
    summary: dict = {
        "machine": machine_info(),
        "workers": workers,
        "config": config,
        "trials": len(trials),
        "trials_with_valid_goals": sum(bool(t["valid_goals"]) for t in trials),
        "median_seconds_per_trial": float(np.median([t["seconds"] for t in trials])),
    }
    for name in ("ground_truth_goal", "predicted_goal"):
        runs = [t[name] for t in trials if name in t]
        if runs:
            summary[name] = success_summary(sum(r["success"] for r in runs), len(runs))
            reached = sum(r["hole_at_a_peg_before_release"] for r in runs)
            summary[name]["hole_at_a_peg_before_release"] = reached / len(runs)
            summary[name]["median_seconds_per_episode"] = float(np.median([r["seconds"] for r in runs]))
    for name in ("goal_metrics", "copy_start_goal_metrics"):
        metrics = [t[name] for t in trials if name in t]
        if metrics:
            summary[name] = {key: float(np.mean([m[key] for m in metrics])) for key in metrics[0]}
    selected = [t for t in trials if "executed_sample" in t]
    if selected:
        threshold = config["goal_threshold_m"]
        valid = [t["sample_goal_rmse"][t["executed_sample"]] < threshold for t in selected]
        summary["executed_goal_valid"] = float(np.mean(valid))
    compared = [t for t in trials if "compared_selections" in t]
    for rule in config.get("compared_selections", ()):
        if not compared:
            break
        runs = [t["compared_selections"][rule] for t in compared]
        outcomes = [r["predicted_goal"]["success"] for r in runs]
        chosen_rmse = [t["sample_goal_rmse"][r["executed_sample"]] for t, r in zip(compared, runs, strict=True)]
        summary.setdefault("compared_selections", {})[rule] = {
            **success_summary(sum(outcomes), len(outcomes)),
            "executed_goal_valid": float(np.mean(np.asarray(chosen_rmse) < config["goal_threshold_m"])),
            "paired": paired_outcomes(
                [t["predicted_goal"]["success"] for t in compared], outcomes, (config["goal_selection"], rule)
            ),
        }
    summary["per_trial"] = trials
    return summary


def evaluate(
    *,
    split: str,
    seed: int,
    trials: int,
    output: Path,
    policy_path: str | None = None,
    goal_policy_path: str | None = None,
    ground_truth_goals: bool = False,
    num_goal_samples: int = 10,
    goal_selection: str = "consensus",
    compared_selections: tuple[str, ...] = (),
    goal_threshold: float = 0.5,
    scorer_path: str | None = None,
    figures: int = 3,
    workers: int = 1,
    device: str = "cpu",
    progress: bool = True,
) -> dict:
    """Run `trials` scenes (seeds seed..seed+trials-1), write `<output>/cloth_hang_eval.json`, return it.

    `compared_selections` are other rules executed on the very same samples of each trial, reported beside
    `goal_selection` with paired counts (`compared_selections` in the report). Each trial runs with torch's
    current thread count (in every worker process, when `workers` > 1).
    """
    if trials < 1:
        raise ValueError(f"trials: must be at least 1, got {trials}")
    if not (goal_policy_path or (policy_path and ground_truth_goals)):
        raise ValueError(
            "nothing to evaluate: give --goal-policy.path (goal metrics; with --policy.path also success with "
            "predicted goals) and/or --policy.path with --ground-truth-goals"
        )
    for rule in (goal_selection, *compared_selections):
        check_goal_selection(rule)
    if goal_selection in compared_selections or len(set(compared_selections)) < len(compared_selections):
        raise ValueError(
            f"compared selections: each rule once, and not the executed one ({goal_selection}); "
            f"got {', '.join(compared_selections)}"
        )
    if compared_selections and not (policy_path and goal_policy_path):
        raise ValueError("compared selections are executed: give --goal-policy.path and --policy.path")
    if ("scorer" in (goal_selection, *compared_selections)) != (scorer_path is not None):
        raise ValueError("goal selection 'scorer' and a scorer path go together: give both or neither")
    from lerobot_taxdpd.goal_predictors import resolve_executor, resolve_goal_predictor, resolve_scorer

    policy_path = _resolved("--policy.path", policy_path, resolve_executor)
    goal_policy_path = _resolved("--goal-policy.path", goal_policy_path, resolve_goal_predictor)
    scorer_path = _resolved("--scorer.path", scorer_path, resolve_scorer)
    output = Path(output)
    output.mkdir(parents=True, exist_ok=True)
    config = {
        "split": split,
        "seeds": f"{seed}..{seed + trials - 1}",
        "policy_path": policy_path,
        "goal_policy_path": goal_policy_path,
        "num_goal_samples": num_goal_samples,
        "goal_selection": goal_selection,
        "compared_selections": list(compared_selections),
        "scorer_path": scorer_path,
        "goal_threshold_m": goal_threshold,
        "device": device,
        "torch_threads_per_trial": torch.get_num_threads(),
    }
    requests = [
        TrialRequest(
            split=split,
            seed=s,
            policy_path=policy_path,
            goal_policy_path=goal_policy_path,
            ground_truth_goals=ground_truth_goals,
            num_goal_samples=num_goal_samples,
            goal_selection=goal_selection,
            compared_selections=tuple(compared_selections),
            goal_threshold=goal_threshold,
            scorer_path=scorer_path,
            figure_dir=str(output / "figures") if i < figures else None,
            device=device,
            torch_threads=torch.get_num_threads(),
        )
        for i, s in enumerate(range(seed, seed + trials))
    ]
    results = tqdm(run_trials(requests, workers), total=len(requests), desc="cloth_hang trials", disable=not progress)
    summary = summarise(list(results), config, workers)
    if goal_policy_path:
        from lerobot_taxdpd.maths.equivariance import PROBE_SCENES

        probed = range(seed, seed + min(trials, PROBE_SCENES))
        summary["equivariance_deg"] = orientation_probe(goal_policy_path, split, probed, device)
    write_json(output / EVAL_FILE, summary)
    return summary


def summary_line(summary: dict, report: Path) -> str:
    """The one line the command prints, as the rigid tasks do: success per kind of goal and the goal errors;
    everything else (per trial, machine, baselines) is in the report."""
    parts = []
    for name, label in (("predicted_goal", "predicted goals"), ("ground_truth_goal", "ground-truth goals")):
        if name in summary:
            s = summary[name]
            parts.append(f"{label} {s['success_rate']:.1%} (95% CI {s['ci95_low']:.1%}-{s['ci95_high']:.1%})")
    for rule, s in summary.get("compared_selections", {}).items():
        interval = f"(95% CI {s['ci95_low']:.1%}-{s['ci95_high']:.1%})"
        parts.append(f"predicted goals chosen by {rule} {s['success_rate']:.1%} {interval}")
    text = f"cloth_hang: success with {', with '.join(parts)} over {summary['trials']} trials" if parts else ""
    if "goal_metrics" in summary:
        m, k = summary["goal_metrics"], summary["config"]["num_goal_samples"]
        goals = f"goal coverage / precision RMSE {m['coverage_rmse']:.3f} / {m['precision_rmse']:.3f} at K = {k}"
        text = f"{text}; {goals}" if text else f"cloth_hang: {goals} over {summary['trials']} trials"
    return f"{text}; report: {report}"


def orientation_probe(goal_policy_path: str, split: str, seeds, device: str = "cpu") -> dict:
    """The equivariance probe (docs/taxdpd.md) on the start cloths and hangers of these scenes: turning the
    hangers should turn the goal with them, turning or tilting the cloth alone should not."""
    from lerobot_taxdpd.maths.equivariance import equivariance_report

    env = ClothHangEnv(split)
    try:
        cloths, hangers = [], []
        for seed in seeds:
            env.reset(options={"scene": sample_scene(split, seed, env.ranges)})
            cloths.append(env.cloth_points())
            hangers.append(env.hanger_points)
    finally:
        env.close()
    with torch.inference_mode():
        return equivariance_report(_goal_predictor(goal_policy_path, device), np.stack(cloths), np.stack(hangers))


def _resolved(flag: str, name_or_path: str | None, resolve: Callable[[str], str]) -> str | None:
    """A checkpoint source resolved (shipped name, folder, Hub id); a bad one is reported under its flag."""
    if not name_or_path:
        return name_or_path
    try:
        return resolve(name_or_path)
    except (ValueError, FileNotFoundError) as error:
        raise type(error)(f"{flag}: {error}") from error


def ship_pipeline(summary: dict, destination: Path) -> Path:
    """Save the evaluated goal predictor as the shipped `cloth_hang` and its gc_dp3 executor as
    `cloth_hang/executor`, each with this evaluation as its metrics (success with the predicted goal and, when
    measured, with ground-truth goals and by the compared selection rules; coverage and precision RMSE for the
    goal predictor). A scorer ships on its own (`python -m lerobot_taxdpd.scoring ship`), so the pipeline's
    rule is one that needs none."""
    from lerobot_taxdpd.goal_predictors import EXECUTOR_DIR, SHIPPED_DIR, load_goal_predictor
    from lerobot_taxdpd.policies.gc_dp3.modeling_gc_dp3 import GcDp3Policy
    from lerobot_taxdpd.sim.pretrain import save_shipped

    config = summary["config"]
    if not (config["goal_policy_path"] and config["policy_path"]) or "predicted_goal" not in summary:
        raise ValueError("--ship: needs --goal-policy.path and --policy.path (success with the predicted goal)")
    if config["goal_selection"] == "scorer":
        raise ValueError(SHIP_WITH_A_SCORER)
    rates = {name: rate_fields(summary[name]) for name in ("predicted_goal", "ground_truth_goal") if name in summary}
    evaluated = {
        "task": CLOTH_TASK,
        "description": TASK_DESCRIPTION,
        "evaluation": f"{summary['trials']} held-out scenes (split {config['split']}, seeds {config['seeds']}), "
        f"K = {config['num_goal_samples']}, goal predictor {_source(config['goal_policy_path'], SHIPPED_DIR)}, "
        f"its {config['goal_selection']} sample executed by gc_dp3 {config['policy_path']}",
        "goal_selection": config["goal_selection"],
        "license": "apache-2.0",
        "success": rates["predicted_goal"],
        **({"success_with_ground_truth_goals": rates["ground_truth_goal"]} if "ground_truth_goal" in rates else {}),
        **(
            {"success_by_selection": {rule: rate_fields(s) for rule, s in summary["compared_selections"].items()}}
            if summary.get("compared_selections")
            else {}
        ),
        "seconds_per_trial": summary["median_seconds_per_trial"],
    }
    shipped = Path(destination) / CLOTH_TASK
    goal_checkpoint = Path(config["goal_policy_path"])
    goal_predictor = load_goal_predictor(goal_checkpoint)
    goal_predictor.metrics = {
        **_kept(goal_predictor.metrics),  # a shipped predictor re-evaluated keeps how it was trained
        **_training(goal_checkpoint),
        **evaluated,
        **_at_k(summary.get("goal_metrics", {}), config["num_goal_samples"]),
        **{
            key: summary[key]
            for key in ("executed_goal_valid", "copy_start_goal_metrics", "equivariance_deg")
            if key in summary
        },
        "coverage_threshold": config["goal_threshold_m"],
    }
    save_shipped(goal_predictor, goal_checkpoint, shipped)
    executor_checkpoint = Path(config["policy_path"])
    executor = GcDp3Policy.from_pretrained(executor_checkpoint)  # save_shipped keeps its average alone
    executor.metrics = {**_kept(executor.metrics), **_training(executor_checkpoint), **evaluated}
    save_shipped(executor, executor_checkpoint, shipped / EXECUTOR_DIR)
    return shipped


def _kept(metrics: dict) -> dict:
    """What a re-shipped checkpoint keeps of its old metrics: how it was trained and measured, less the rules
    compared in the old evaluation (this one's replace them, or say none were compared)."""
    return {key: value for key, value in metrics.items() if key != "success_by_selection"}


def rate_fields(summary: dict) -> dict:
    """A success summary's rate and interval, without what else the report keeps beside them."""
    return {k: summary[k] for k in ("success_rate", "ci95_low", "ci95_high", "trials")}


def _source(path: str, shipped_dir: Path) -> str:
    """A checkpoint as a user names it: a shipped one by its name, anything else by its path."""
    return f"{Path(path).name} (shipped)" if Path(path).resolve().parent == shipped_dir.resolve() else path


def _at_k(goal_metrics: dict, num_samples: int) -> dict:
    """Goal metrics under the rigid tasks' names: coverage and precision become coverage@K and precision@K."""
    renamed = {"coverage": f"coverage@{num_samples}", "precision": f"precision@{num_samples}"}
    return {renamed.get(key, key): value for key, value in goal_metrics.items()}


def _training(checkpoint: Path) -> dict:
    """How a checkpoint was trained, from the train_config.json lerobot-train saved beside it ({} without one);
    its command as anyone can type it (the shipped recipe and flags), not the folders it ran in."""
    train_config = checkpoint / "train_config.json"
    if not train_config.is_file():
        return {}
    trained = json.loads(train_config.read_text())
    dataset = trained.get("dataset", {})
    return {
        "data": f"dataset {dataset.get('repo_id', '?')} ({dataset.get('root', '?')})",
        "training_command": portable_train_command(trained),
        "training_steps": trained.get("steps"),
        "batch_size": trained.get("batch_size"),
    }
