"""A scorer measured on held-out trials beside the first sample, paired, and shipped beside its goal predictor.

The same trials run twice, once executing the first sample and once the scorer's choice; the harness draws a
trial's K samples from its seed, so both rules choose among the very same samples and every difference in
outcome is the choice. The shipped scorer lives in `<ship>/<task>/scorer/` (config, weights, metrics with this
evaluation, a card), where `--goal-selection scorer` finds it by the predictor's name.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import shlex
import shutil
from pathlib import Path

import numpy as np

from lerobot_taxdpd.data.schema import CLOTH_TASK, METRICS_FILE
from lerobot_taxdpd.goal_predictors import weights_digest
from lerobot_taxdpd.maths.metrics import paired_outcomes
from lerobot_taxdpd.policies.goal_scorer import GoalScorerConfig

SCORER_FILES = ("config.json", "model.safetensors")


def evaluate_choice(
    task_name: str,
    goal_policy: str,
    scorer_path: str,
    seeds: range,
    num_samples: int = 10,
    *,
    workers: int = 1,
    reports: Path | None = None,
    search: dict | None = None,
) -> dict:
    """Success of the task's baseline rule (the first sample; cloth_hang: the consensus one, its default) and of
    the scorer's choice on the same held-out trials, with paired counts. `search` overrides the scorer's search
    settings (`search_extent_mm`, `search_step_mm`); a scorer that searches is also measured choosing among the
    samples as sampled, so the search's own gain shows. cloth_hang also executes the first sample, runs
    `workers` processes and writes its per-trial report in `reports` (default: `<scorer>/evaluation`)."""
    from lerobot_taxdpd.goal_predictors import load_goal_predictor, load_scorer

    scorer = load_scorer(scorer_path)
    scorer.config = dataclasses.replace(scorer.config, **(search or {}))
    if task_name == CLOTH_TASK:
        if scorer.config.search_extent_mm:  # given here or carried in its config: neither reaches cloth's workers
            raise ValueError(f"{CLOTH_TASK}: the scorer's search around its samples is for rigid tasks")
        return _evaluate_cloth_choice(goal_policy, scorer_path, seeds, num_samples, workers, reports)
    from lerobot_taxdpd.sim.harness import evaluate
    from lerobot_taxdpd.sim.predictors import observed_as_trained
    from lerobot_taxdpd.sim.tasks import get_task
    from lerobot_taxdpd.sim.trials import make_trial

    predictor = load_goal_predictor(goal_policy)
    task = observed_as_trained(get_task(task_name), predictor)
    trials = [make_trial(task, seed, "test") for seed in seeds]
    first = evaluate(predictor, trials, num_samples, goal_selection="first")
    chosen = evaluate(predictor, trials, num_samples, goal_selection="scorer", scorer=scorer)
    figures = _rule_figures(first, "baseline") | _rule_figures(chosen, "scorer")
    figures["paired"] = _paired(chosen, first, ("scorer", "baseline"))
    if scorer.config.search_extent_mm:
        plain = copy.deepcopy(scorer)
        plain.config = dataclasses.replace(scorer.config, search_extent_mm=0.0)
        unmoved = evaluate(predictor, trials, num_samples, goal_selection="scorer", scorer=plain)
        figures |= _rule_figures(unmoved, "scorer_without_search") | {
            "search": {"extent_mm": scorer.config.search_extent_mm, "step_mm": scorer.config.search_step_mm},
            "paired_search": _paired(chosen, unmoved, ("search", "without_search")),
        }
    return {
        "task": task.name,
        "trials": f"{len(trials)} held-out trials (test geometry, seeds {seeds.start}..{seeds.stop - 1}), "
        f"K = {num_samples}",
        "baseline_rule": "first",
    } | figures


def _rule_figures(report: dict, key: str) -> dict:
    """One rule's evaluation report as the card reads it, under `key`: its success and median errors."""
    return {
        key: report["success"],
        f"{key}_translation_error_mm": report["translation_error_mm"]["median"],
        f"{key}_rotation_error_deg": report["rotation_error_deg"]["median"],
    }


def _paired(a: dict, b: dict, names: tuple[str, str]) -> dict[str, int]:
    """Paired outcomes of two evaluation reports of the same trials."""
    return paired_outcomes([t["success"] for t in a["per_trial"]], [t["success"] for t in b["per_trial"]], names)


def _evaluate_cloth_choice(
    goal_policy: str, scorer_path: str, seeds: range, num_samples: int, workers: int, reports: Path | None
) -> dict:
    """cloth_hang: one pass over the scenes executes the scorer's choice, the consensus sample and the first, each
    hung by the executor whose outcomes the scorer learnt."""
    from lerobot_taxdpd.sim.cloth.evaluation import EVAL_FILE, evaluate

    executor = json.loads((Path(scorer_path) / METRICS_FILE).read_text())["collection"]["executor"]
    reports = Path(reports) if reports is not None else Path(scorer_path) / "evaluation"
    summary = evaluate(
        split="test",
        seed=seeds.start,
        trials=len(seeds),
        output=reports,
        policy_path=executor,
        goal_policy_path=goal_policy,
        num_goal_samples=num_samples,
        goal_selection="scorer",
        compared_selections=("consensus", "first"),
        scorer_path=scorer_path,
        figures=0,
        workers=workers,
    )
    return cloth_choice(summary) | {"report": str(reports / EVAL_FILE)}


def cloth_choice(summary: dict) -> dict:
    """A cloth evaluation report (`sim eval --task cloth_hang`, the scorer's choice executed, the consensus and
    first samples compared on the same samples) as a scorer's evaluation: rates, paired counts, valid shares."""
    config, compared = summary["config"], summary.get("compared_selections", {})
    if config["goal_selection"] != "scorer" or not {"consensus", "first"} <= set(compared):
        raise ValueError(
            "a cloth scorer is measured by executing its choice with the consensus and first samples compared "
            "(--goal-selection scorer --compare-selections consensus first)"
        )
    from lerobot_taxdpd.sim.cloth.evaluation import rate_fields

    runs = [t for t in summary["per_trial"] if "predicted_goal" in t]
    paired = compared["consensus"]["paired"]  # the scorer's outcomes against the consensus's, as the report counts
    threshold = config["goal_threshold_m"]
    return {
        "task": CLOTH_TASK,
        "trials": f"{summary['trials']} held-out scenes ({config['split']} geometry, seeds {config['seeds']}), "
        f"K = {config['num_goal_samples']}, the chosen goal hung by gc_dp3",
        "baseline_rule": "consensus",
        "baseline": rate_fields(compared["consensus"]),
        "scorer": rate_fields(summary["predicted_goal"]),
        "paired": {"both": paired["both"], "only_scorer": paired["only_scorer"],
                   "only_baseline": paired["only_consensus"], "neither": paired["neither"]},  # fmt: skip
        "first_sample": rate_fields(compared["first"]),
        "executed_goal_valid": {
            "scorer": summary["executed_goal_valid"],
            "consensus": compared["consensus"]["executed_goal_valid"],
            "first": compared["first"]["executed_goal_valid"],
            "best_of_k": float(np.mean([min(t["sample_goal_rmse"]) < threshold for t in runs])),
        },
    }


def commands(metrics: dict, task: str) -> list[str]:
    """The collect (one per run of consecutive seeds) and train commands that remake a scorer, as anyone can
    type them (no machine's folders)."""
    collection = metrics["collection"]
    data = f"data/scorer/{task}"
    lines = []
    for run in metrics["collected_seeds"].split(", "):
        first, last = run.split("..")
        collect = ["python", "-m", "lerobot_taxdpd.scoring", "collect", "--task", task, "--goal-policy.path",
                   task, "--seeds", first, last, "--output", data, "--num-samples",
                   str(collection["num_samples"])]  # fmt: skip
        if collection.get("executor", task) != task:
            collect += ["--executor", collection["executor"]]
        if collection.get("shifted_copies"):
            collect += ["--shifted-copies", str(collection["shifted_copies"]),
                        "--shift-extent-mm", f"{collection['shift_extent_mm']:g}"]  # fmt: skip
        lines.append(shlex.join(collect))
    train = ["python", "-m", "lerobot_taxdpd.scoring", "train", "--collection", data, "--output",
             f"outputs/scorer/{task}", "--steps", str(metrics["steps"]), "--batch-scenes",
             str(metrics["batch_scenes"]), "--seed", str(metrics["seed"])]  # fmt: skip
    if metrics.get("num_goal_points", GoalScorerConfig.num_goal_points) != GoalScorerConfig.num_goal_points:
        train += ["--num-goal-points", str(metrics["num_goal_points"])]
    if metrics.get("start_displacement"):
        train.append("--start-displacement")
    if metrics.get("search_extent_mm"):
        train += ["--search-extent-mm", f"{metrics['search_extent_mm']:g}",
                  "--search-step-mm", f"{metrics['search_step_mm']:g}"]  # fmt: skip
    return [*lines, shlex.join(train)]


def ship_scorer(
    scorer_dir: Path, goal_policy: str, evaluation: dict, destination: Path, search: dict | None = None
) -> Path:
    """Copy a trained scorer to `<destination>/<task>/scorer/` with this evaluation in its metrics and a card,
    and `search` (the settings it was evaluated with) in its config; refused when `goal_policy` is not the
    predictor whose samples it learnt."""
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
    if target.resolve() != scorer_dir.resolve():  # a shipped scorer re-measured stays where it is
        for name in SCORER_FILES:
            shutil.copyfile(scorer_dir / name, target / name)
    config = {**json.loads((target / "config.json").read_text()), **(search or {})}
    defaults = GoalScorerConfig()
    if config.get("search_extent_mm"):  # the grid in full, whatever the scorer was trained with
        config.setdefault("search_step_mm", defaults.search_step_mm)
    (target / "config.json").write_text(json.dumps(config, indent=2))
    metrics |= {
        "search_extent_mm": config.get("search_extent_mm", defaults.search_extent_mm),
        "search_step_mm": config.get("search_step_mm", defaults.search_step_mm),
        "evaluation": evaluation,
    }
    metrics["commands"] = commands(metrics, task)
    (target / METRICS_FILE).write_text(json.dumps(metrics, indent=2))
    (target / "README.md").write_text(card(metrics))
    return target


def _rate(summary: dict, bold: bool = False) -> str:
    text = f"{summary['success_rate']:.0%} ({summary['ci95_low']:.0%}-{summary['ci95_high']:.0%})"
    return f"**{text}**" if bold else text


_RULE_LABELS = {
    "first": "first (the paper's one shot)",
    "consensus": "consensus (the sample the others agree with)",
    "scorer": "the scorer's choice",
}


def _result_rows(e: dict) -> tuple[str, list[str]]:
    """The card's results table: one row per rule measured (rigid: first and scorer, with their pose errors;
    cloth: first, consensus and scorer, with how often the executed goal was a valid one)."""
    if e["task"] == CLOTH_TASK:
        rates = {"first": e["first_sample"], "consensus": e["baseline"], "scorer": e["scorer"]}
        valid = e["executed_goal_valid"]
        rows = [f"| {_RULE_LABELS[r]} | {_rate(rate, r == 'scorer')} | {valid[r]:.0%} |" for r, rate in rates.items()]
        return "| executed sample | success | executed goal valid |\n|---|---|---|", rows
    measured = [(_RULE_LABELS[e["baseline_rule"]], "baseline")]
    if "search" in e:
        measured.append(("the scorer's choice among the samples as sampled", "scorer_without_search"))
        label = f"the scorer's choice, moved by its search (up to {e['search']['extent_mm']:g} mm in x and y, "
        measured.append((label + f"a {e['search']['step_mm']:g} mm grid)", "scorer"))
    else:
        measured.append((_RULE_LABELS["scorer"], "scorer"))
    rows = []
    for label, key in measured:
        errors = f"{e[f'{key}_translation_error_mm']:.1f} mm / {e[f'{key}_rotation_error_deg']:.1f} deg"
        rows.append(f"| {label} | {_rate(e[key], key == 'scorer')} | {errors} |")
    return "| executed sample | success | translation / rotation (median) |\n|---|---|---|", rows


def card(metrics: dict) -> str:
    """The scorer's model card: what it chooses among, what it was trained on, and what choosing by it measured."""
    e, held, p = metrics["evaluation"], metrics["held_back_scenes"], metrics["evaluation"]["paired"]
    *collect, train = metrics["commands"]
    header, rows = _result_rows(e)
    table = "\n".join([header, *rows])
    baseline = e["baseline_rule"]
    best = f" The best of the K was a valid goal in {e['executed_goal_valid']['best_of_k']:.0%} of the scenes." if (
        "executed_goal_valid" in e
    ) else ""
    outcomes = "(hung, not hung)" if e["task"] == CLOTH_TASK else "(successful, failed)"
    search = ""
    if "paired_search" in e:
        q = e["paired_search"]
        search = (f" The search against the same choice unmoved: both {q['both']}, only searched {q['only_search']}, "
                  f"only unmoved {q['only_without_search']}, neither {q['neither']}.")  # fmt: skip
    ordered = held.get("pairs_ordered")
    pairs = f"; it orders {ordered:.0%} of their {outcomes} sample pairs right" if ordered is not None else ""
    use = f"python -m lerobot_taxdpd.sim eval --task {e['task']} --goal-policy.path {e['task']}"
    use += " --policy.path cloth_hang" * (e["task"] == CLOTH_TASK) + " --goal-selection scorer"
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

{e['trials']}, the same samples chosen each way:

{table}

Paired against the {baseline} sample: both {p['both']}, only the scorer's {p['only_scorer']}, only the
{baseline} {p['only_baseline']}, neither {p['neither']}.{best}{search} On {held.get('scenes', 0)} training-geometry
scenes held back from its training: the scorer's choice {held.get('scorer', 0):.0%}, the first sample
{held.get('first_sample', 0):.0%}, the best of the K {held.get('any_sample', 0):.0%}{pairs}.

## Use

```bash
{use}
```

## Training

```bash
{chr(10).join(collect)}
{train}
```
"""
