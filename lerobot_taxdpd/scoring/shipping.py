"""A scorer measured on held-out trials beside the first sample, paired, and shipped beside its goal predictor.

The same trials run twice, once executing the first sample and once the scorer's choice; the harness draws a
trial's K samples from its seed, so both rules choose among the very same samples and every difference in
outcome is the choice. The shipped scorer lives in `<ship>/<task>/scorer/` (config, weights, metrics with this
evaluation, a card), where `--goal-selection scorer` finds it by the predictor's name.
"""

from __future__ import annotations

import json
import shlex
import shutil
from pathlib import Path

from lerobot_taxdpd.data.schema import METRICS_FILE
from lerobot_taxdpd.goal_predictors import weights_digest

SCORER_FILES = ("config.json", "model.safetensors")


def evaluate_choice(task_name: str, goal_policy: str, scorer_path: str, seeds: range, num_samples: int = 10) -> dict:
    """Success of the first sample and of the scorer's choice on the same held-out trials, with paired counts."""
    from lerobot_taxdpd.goal_predictors import load_goal_predictor, load_scorer
    from lerobot_taxdpd.sim.harness import evaluate
    from lerobot_taxdpd.sim.tasks import get_task
    from lerobot_taxdpd.sim.trials import make_trial

    task = get_task(task_name)
    predictor, scorer = load_goal_predictor(goal_policy), load_scorer(scorer_path)
    trials = [make_trial(task, seed, "test") for seed in seeds]
    first = evaluate(predictor, trials, num_samples, goal_selection="first")
    chosen = evaluate(predictor, trials, num_samples, goal_selection="scorer", scorer=scorer)
    a = [t["success"] for t in chosen["per_trial"]]
    b = [t["success"] for t in first["per_trial"]]
    return {
        "task": task.name,
        "trials": f"{len(trials)} held-out trials (test geometry, seeds {seeds.start}..{seeds.stop - 1}), "
        f"K = {num_samples}",
        "first_sample": first["success"],
        "scorer": chosen["success"],
        "paired": {
            "both": sum(x and y for x, y in zip(a, b, strict=True)),
            "only_scorer": sum(x and not y for x, y in zip(a, b, strict=True)),
            "only_first": sum(y and not x for x, y in zip(a, b, strict=True)),
            "neither": sum(not (x or y) for x, y in zip(a, b, strict=True)),
        },
        "scorer_translation_error_mm": chosen["translation_error_mm"]["median"],
        "scorer_rotation_error_deg": chosen["rotation_error_deg"]["median"],
        "first_translation_error_mm": first["translation_error_mm"]["median"],
        "first_rotation_error_deg": first["rotation_error_deg"]["median"],
    }


def commands(metrics: dict, task: str) -> list[str]:
    """The collect and train commands that remake a scorer, as anyone can type them (no machine's folders)."""
    collection = metrics["collection"]
    first, last = (int(x) for x in metrics["collected_seeds"].split(".."))
    data = f"data/scorer/{task}"
    collect = ["python", "-m", "lerobot_taxdpd.scoring", "collect", "--task", task, "--goal-policy.path",
               task, "--seeds", str(first), str(last), "--output", data, "--num-samples",
               str(collection["num_samples"])]  # fmt: skip
    train = ["python", "-m", "lerobot_taxdpd.scoring", "train", "--collection", data, "--output",
             f"outputs/scorer/{task}", "--steps", str(metrics["steps"]), "--batch-scenes",
             str(metrics["batch_scenes"]), "--seed", str(metrics["seed"])]  # fmt: skip
    return [shlex.join(collect), shlex.join(train)]


def ship_scorer(scorer_dir: Path, goal_policy: str, evaluation: dict, destination: Path) -> Path:
    """Copy a trained scorer to `<destination>/<task>/scorer/` with this evaluation in its metrics and a card;
    refused when `goal_policy` is not the predictor whose samples it learnt."""
    from lerobot_taxdpd.goal_predictors import resolve_goal_predictor

    scorer_dir, task = Path(scorer_dir), evaluation["task"]
    metrics = json.loads((scorer_dir / METRICS_FILE).read_text())
    learnt = metrics["collection"]["goal_policy_weights"]
    shipped_with = weights_digest(resolve_goal_predictor(goal_policy))
    if learnt != shipped_with:
        raise ValueError(
            f"{scorer_dir}: trained on the samples of goal predictor weights {learnt}, not of {goal_policy} "
            f"({shipped_with}); collect and train it for {goal_policy} first"
        )
    target = Path(destination) / task / "scorer"
    target.mkdir(parents=True, exist_ok=True)
    for name in SCORER_FILES:
        shutil.copyfile(scorer_dir / name, target / name)
    metrics = {**metrics, "evaluation": evaluation, "commands": commands(metrics, task)}
    (target / METRICS_FILE).write_text(json.dumps(metrics, indent=2))
    (target / "README.md").write_text(card(metrics))
    return target


def _rate(summary: dict) -> str:
    return f"{summary['success_rate']:.0%} ({summary['ci95_low']:.0%}-{summary['ci95_high']:.0%})"


def card(metrics: dict) -> str:
    """The scorer's model card: what it chooses among, what it was trained on, and what choosing by it measured."""
    e, held, p = metrics["evaluation"], metrics["held_back_scenes"], metrics["evaluation"]["paired"]
    collect, train = metrics["commands"]
    first_errors = f"{e['first_translation_error_mm']:.1f} mm / {e['first_rotation_error_deg']:.1f} deg"
    scorer_errors = f"{e['scorer_translation_error_mm']:.1f} mm / {e['scorer_rotation_error_deg']:.1f} deg"
    return f"""---
library_name: lerobot_taxdpd
tags:
- goal-scorer
- robotics
license: apache-2.0
---

# Goal scorer for `{e['task']}`

Chooses which of the K goal samples of the shipped `{e['task']}` goal predictor to execute: a DP3-style
encoder of each candidate goal point and its nearest scene points (contact geometry), one success logit per
candidate. Trained on that predictor's own samples (weights `{metrics['collection']['goal_policy_weights']}`),
each executed in simulation, on {metrics['training_scenes']} training-geometry scenes (seeds
{metrics['training_seeds']}; the predictor's demonstrations use seeds from 0).

## Results

{e['trials']}, the same samples chosen two ways:

| executed sample | success | translation / rotation (median) |
|---|---|---|
| first (the paper's one shot) | {_rate(e['first_sample'])} | {first_errors} |
| the scorer's choice | **{_rate(e['scorer'])}** | {scorer_errors} |

Paired: both {p['both']}, only the scorer's {p['only_scorer']}, only the first {p['only_first']}, neither
{p['neither']}. On {held.get('scenes', 0)} training-geometry scenes held back from its training: the scorer's
choice {held.get('scorer', 0):.0%}, the first sample {held.get('first_sample', 0):.0%}, the best of the K
{held.get('any_sample', 0):.0%}.

## Use

```bash
python -m lerobot_taxdpd.sim eval --task {e['task']} --goal-policy.path {e['task']} --goal-selection scorer
```

## Training

```bash
{collect}
{train}
```
"""
