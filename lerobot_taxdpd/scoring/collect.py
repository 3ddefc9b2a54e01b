"""Labelled goal samples for a scorer: a goal predictor's K samples on training scenes, each one executed.

Only the training geometry is used (`split="train"`), at scene seeds the caller picks; pick seeds the goal
predictor's demonstrations did not use (they start at 0), so the samples are as wrong as on unseen scenes.
The held-out trials that evaluations report are never touched.

Scenes are written in shards of `shard_size` (`shard_<first>_<last>.npz`, each written whole, then renamed),
so a collection runs in legs: a rerun with the same arguments skips the shards in place and adds the rest, and
shards are the unit that `workers` processes share out.
`collection.json` records what made them (task, goal predictor and its weights' hash, K, split), and a rerun
with other options is refused rather than mixed in.

A scorer that searches (`GoalScorerConfig.search_extent_mm`) rates samples moved where the predictor did not put
them; `shifted_copies` adds such candidates to each scene, copies of its samples moved horizontally at random
within `shift_extent_mm` and executed like the rest, so that the scorer learns what a shift does.
"""

from __future__ import annotations

import functools
import json
import multiprocessing
import os
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from lerobot_taxdpd.data.schema import CLOTH_TASK
from lerobot_taxdpd.maths.geometry import transform_points
from lerobot_taxdpd.maths.metrics import score_against_valid_goals

COLLECTION_FILE = "collection.json"
#: Arrays of a shard, per scene: seed (n,), scene (n, S, 3), object (n, N, 3), samples (n, K, N, 3), success
#: (n, K) from executing each sample, rmse (n, K) to the nearest valid goal (metres; cloth units on cloth_hang; NaN
#: where the scene has none).
SHARD_ARRAYS = ("seed", "scene", "object", "samples", "success", "rmse")


def shard_paths(folder: Path) -> list[Path]:
    return sorted(Path(folder).glob("shard_*.npz"))


def label_samples(trial, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Execute every sample of one trial (RANSAC-SVD pose, then the task's controller and success check, as the
    harness executes its chosen one): success (K,) and RMSE (K,) to the nearest valid goal."""
    from lerobot_taxdpd.sim.harness import execute_sample

    object_points = trial.object_points.astype(np.float64)
    success = np.array([execute_sample(trial, sample)[1].success for sample in samples], dtype=bool)
    goals = np.concatenate([transform_points(t, object_points) for t in trial.valid_transforms()])
    return success, score_against_valid_goals(samples, goals).nearest_rmse.astype(np.float32)


def collect(
    task_name: str,
    goal_policy: str,
    seeds: Iterable[int],
    output: Path,
    *,
    num_samples: int = 10,
    shard_size: int = 50,
    executor: str | None = None,
    workers: int = 1,
    progress: bool = True,
    shifted_copies: int = 0,
    shift_extent_mm: float = 0.0,
) -> list[Path]:
    """Collect (or finish collecting) labelled samples of `task_name`'s training scenes `seeds` into `output`.

    Rigid tasks execute each sample as `sim eval` does; `cloth_hang` hangs the cloth with the gc_dp3 `executor`
    (default: the one shipped with the goal predictor's name) conditioned on each sample, and finds the scene's
    valid goals for the RMSE with an expert rollout per hole and hanger (about a fifth of a scene's time;
    NaN where none hangs). With `workers` > 1,
    shards are labelled in that many processes (one torch thread each), each shard by one of them. Rigid tasks
    can add `shifted_copies` candidates a scene: samples moved by up to `shift_extent_mm` in x and y (the K
    samples come first, so rules that read the first sample still see the predictor's)."""
    from lerobot_taxdpd.goal_predictors import resolve_executor, resolve_goal_predictor, weights_digest

    if num_samples < 2:
        raise ValueError(f"num_samples: a scorer chooses among samples, so at least 2, got {num_samples}")
    if workers < 1:
        raise ValueError(f"workers: must be at least 1, got {workers}")
    if shifted_copies < 0 or (shifted_copies and shift_extent_mm <= 0):
        raise ValueError(
            f"shifted copies: need a count >= 0 and, with copies, an extent > 0 mm; got {shifted_copies} and "
            f"{shift_extent_mm}"
        )
    source = resolve_goal_predictor(goal_policy)
    details = {
        "task": task_name,
        "split": "train",
        "goal_policy": str(goal_policy),
        "goal_policy_weights": weights_digest(source),
        "num_samples": num_samples,
    }
    if shifted_copies:  # recorded only when used, so collections made before still match their reruns
        details |= {"shifted_copies": shifted_copies, "shift_extent_mm": shift_extent_mm}
    resolved_executor = None
    if task_name == CLOTH_TASK:
        if shifted_copies:
            raise ValueError(f"shifted copies: measured for rigid tasks, not {task_name}")
        executor = str(executor or goal_policy)  # recorded as given, as the goal predictor is: no machine's folders
        resolved_executor = resolve_executor(executor)
        details |= {"executor": executor, "executor_weights": weights_digest(resolved_executor)}
    elif executor is not None:
        raise ValueError(f"executor: only cloth_hang executes its goals with a policy, not {task_name}")
    output = Path(output)
    output.mkdir(parents=True, exist_ok=True)
    _check_collection(output / COLLECTION_FILE, details)
    seeds = list(seeds)
    chunks = [seeds[i : i + shard_size] for i in range(0, len(seeds), shard_size)]
    todo = [c for c in chunks if not (output / _shard_name(c)).is_file()]
    shifts = (shifted_copies, shift_extent_mm / 1000)
    job = functools.partial(_collect_shard, task_name, source, resolved_executor, num_samples, shifts, output)
    bar = tqdm(total=sum(map(len, todo)), desc=f"{task_name} scenes", disable=not progress)
    if workers == 1 or len(todo) <= 1:
        for chunk in todo:
            job(chunk, bar.update)
    else:
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(min(workers, len(todo)), mp_context=context, initializer=torch.set_num_threads,
                                 initargs=(1,)) as pool:  # fmt: skip
            for done in as_completed([pool.submit(job, chunk) for chunk in todo]):
                bar.update(done.result())
    bar.close()
    return shard_paths(output)


def _collect_shard(
    task_name: str,
    source: str,
    executor: str | None,
    num_samples: int,
    shifts: tuple[int, float],
    output: Path,
    chunk: list[int],
    on_scene: Callable[[], object] | None = None,
) -> int:
    """Label the scenes of one shard and write it whole; the number of scenes (what a worker reports back).
    `shifts`: how many shifted copies a scene gets, and how far (metres) they may move."""
    if task_name == CLOTH_TASK:
        label_scene = functools.partial(_cloth_scene, source, executor, num_samples)
    else:
        label_scene = _rigid_labeller(task_name, source, num_samples, *shifts)
    rows = {name: [] for name in SHARD_ARRAYS}
    for seed in chunk:
        for name, value in label_scene(seed).items():
            rows[name].append(value)
        if on_scene is not None:
            on_scene()
    _write_shard(output / _shard_name(chunk), {name: np.stack(values) for name, values in rows.items()})
    return len(chunk)


def _row(seed: int, scene, obj, samples, success, rmse) -> dict[str, np.ndarray]:
    return {
        "seed": np.int64(seed),
        "scene": np.asarray(scene, dtype=np.float32),
        "object": np.asarray(obj, dtype=np.float32),
        "samples": np.asarray(samples, dtype=np.float32),
        "success": np.asarray(success, dtype=bool),
        "rmse": np.asarray(rmse, dtype=np.float32),
    }


def shifted_copies_of(samples: np.ndarray, copies: int, extent: float, rng: np.random.Generator) -> np.ndarray:
    """`copies` clouds (copies, N, 3): samples drawn at random, each moved by a uniform offset within +-`extent`
    in x and y (metres)."""
    chosen = samples[rng.integers(len(samples), size=copies)]
    offsets = np.concatenate([rng.uniform(-extent, extent, (copies, 2)), np.zeros((copies, 1))], 1)
    return chosen + offsets[:, None]


@functools.lru_cache(maxsize=1)  # one per process, whatever the number of shards it labels
def _rigid_labeller(
    task_name: str, source: str, num_samples: int, shifted_copies: int = 0, shift_extent: float = 0.0
) -> Callable[[int], dict[str, np.ndarray]]:
    from lerobot_taxdpd.goal_predictors import load_goal_predictor
    from lerobot_taxdpd.sim.harness import sample_trial_goals
    from lerobot_taxdpd.sim.predictors import observed_as_trained
    from lerobot_taxdpd.sim.tasks import get_task
    from lerobot_taxdpd.sim.trials import make_trial

    predictor = load_goal_predictor(source)
    task = observed_as_trained(get_task(task_name), predictor)

    def label(seed: int) -> dict[str, np.ndarray]:
        trial = make_trial(task, seed, "train")
        samples = sample_trial_goals(predictor, trial, num_samples)
        if shifted_copies:  # drawn from the scene's seed, so a shard is the same whoever labels it
            copies = shifted_copies_of(samples, shifted_copies, shift_extent, np.random.default_rng(seed))
            samples = np.concatenate([samples, copies])
        return _row(seed, trial.scene_points, trial.object_points, samples, *label_samples(trial, samples))

    return label


def _cloth_scene(goal_policy: str, executor: str, num_samples: int, seed: int) -> dict[str, np.ndarray]:
    """One cloth scene: K goals sampled from the start cloth and the hangers, each hung by the executor, and
    each one's RMSE to the nearest goal the expert hangs from this start (NaN where it hangs none)."""
    from lerobot_taxdpd.maths.metrics import pairwise_rmse
    from lerobot_taxdpd.sim.cloth.env import ClothHangEnv
    from lerobot_taxdpd.sim.cloth.evaluation import cached_executor, policy_controller, sample_goals
    from lerobot_taxdpd.sim.cloth.rollout import rollout, valid_goal_clouds
    from lerobot_taxdpd.sim.cloth.scene import sample_scene

    env = ClothHangEnv("train")
    try:
        scene = sample_scene("train", seed, env.ranges)
        goals = list(valid_goal_clouds(env, scene).values())  # as `sim eval` finds them, before it samples
        cloth, hangers = env.cloth_points(), env.hanger_points
        samples = sample_goals(goal_policy, cloth, hangers, num_samples, seed)
        policy = cached_executor(executor, "cpu")
        success = []
        for sample in samples:
            torch.manual_seed(seed)  # as the evaluation seeds its executor's rollout
            success.append(rollout(env, scene, policy_controller(*policy, sample)).success)
    finally:
        env.close()
    rmse = pairwise_rmse(samples, np.stack(goals)).min(1) if goals else np.full(num_samples, np.nan)
    return _row(seed, hangers, cloth, samples, success, rmse)


def _shard_name(seeds: list[int]) -> str:
    return f"shard_{seeds[0]:06d}_{seeds[-1]:06d}.npz"


def _write_shard(path: Path, arrays: dict[str, np.ndarray]) -> None:
    partial = path.with_suffix(".partial.npz")
    np.savez(partial, **arrays)
    os.replace(partial, path)  # a leg stopped mid-shard leaves no half-written shard behind


def _check_collection(path: Path, details: dict) -> None:
    if path.is_file():
        held = json.loads(path.read_text())
        differences = {k: (held.get(k), v) for k, v in details.items() if held.get(k) != v}
        if differences:
            listed = ", ".join(f"{k} {old!r}, not {new!r}" for k, (old, new) in differences.items())
            raise ValueError(
                f"{path.parent}: holds samples collected with other options ({listed}); use another folder"
            )
        return
    path.write_text(json.dumps(details, indent=2))


def load_collection(folder: Path) -> tuple[dict, dict[str, np.ndarray]]:
    """What made a collection and its shards, concatenated in seed order."""
    folder = Path(folder)
    if not (folder / COLLECTION_FILE).is_file():
        raise FileNotFoundError(f"{folder}: no {COLLECTION_FILE}; collect samples there first")
    shards = shard_paths(folder)
    if not shards:
        raise FileNotFoundError(f"{folder}: no shard_*.npz; the collection has not written a shard yet")
    loaded = []
    for shard in shards:
        with np.load(shard) as data:
            missing = [name for name in SHARD_ARRAYS if name not in data]
            if missing:
                raise ValueError(f"{shard}: missing arrays {missing}")
            loaded.append({name: data[name] for name in SHARD_ARRAYS})
    arrays = {name: np.concatenate([shard[name] for shard in loaded]) for name in SHARD_ARRAYS}
    return json.loads((folder / COLLECTION_FILE).read_text()), arrays
