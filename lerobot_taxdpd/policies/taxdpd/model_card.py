"""The model card written beside every saved `taxdpd` checkpoint and pushed with it to the Hub.

With measured metrics (`metrics.json`, written by `sim pretrain` and `sim eval --ship`), the card names the
task in its title, gives a runnable example on a held-out scene of that task, states the limitations with
the measured numbers, and lists the metrics as model-index entries (`EvalResult`), which the Hub shows as
evaluation results. Without metrics it describes the model and how to load it.
"""

from __future__ import annotations

import json

from huggingface_hub import EvalResult, ModelCard

from lerobot_taxdpd.data.schema import CLOTH_TASK, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.policies.model_cards import INSTALL, assemble, card_data, config_table

_SWITCHES = (
    "use_gmm",
    "disentangled",
    "local_diffusion",
    "encoder",
    "use_reconstruction_embedding",
    "use_deformation_embedding",
    "use_rotation_noise",
)
_SHAPE = (
    "hidden_dim",
    "num_blocks",
    "num_heads",
    "num_object_points",
    "num_scene_points",
    "point_scale",
    "object_scale",
)
_SAMPLING = ("sampler", "num_inference_steps", "num_train_timesteps", "gmm_frames", "frame_temperature")
_TRAINING = ("prediction_type", "rotation_noise", "start_yaw_range", "start_tilt_range")
#: metrics.json entry -> (model-index metric type, what the number is); medians of the per-trial values.
_MEDIANS = {
    "translation_error_mm": ("translation_error_mm", "median translation error (mm)"),
    "rotation_error_deg": ("rotation_error_deg", "median rotation error (deg)"),
    "rmse_mm": ("rmse_mm", "median per-point RMSE of the executed sample (mm)"),
    "winner_take_all_rmse_mm": ("winner_take_all_rmse_mm", "median winner-take-all RMSE over K samples (mm)"),
    "gripper_translation_error_mm": ("gripper_translation_error_mm", "median gripper translation error (mm)"),
    "gripper_rotation_error_deg": ("gripper_rotation_error_deg", "median gripper rotation error (deg)"),
}
_VALUES = {
    "coverage_rmse": ("coverage_rmse", "coverage RMSE"),
    "precision_rmse": ("precision_rmse", "precision RMSE"),
    "executed_goal_valid": ("executed_goal_valid", "fraction of scenes whose executed goal sample is a valid goal"),
}


def _rate(success: dict) -> str:
    return (
        f"{success['success_rate']:.0%} (95% CI {success['ci95_low']:.0%}-{success['ci95_high']:.0%}, "
        f"{success['trials']} trials)"
    )


def eval_results(metrics: dict) -> list[EvalResult]:
    """The measured metrics as model-index entries, one per number, all on the task's held-out split."""
    task, success = metrics.get("task"), metrics.get("success")
    if not task or not success:
        return []
    where = dict(
        task_type="robotics",
        task_name=metrics.get("description", task),
        dataset_type=f"lerobot_taxdpd/sim/{task}",
        dataset_name=f"{task}, procedural pybullet benchmark, held-out geometry",
        dataset_split="test",
    )

    def entry(metric_type: str, name: str, value: float) -> EvalResult:
        return EvalResult(metric_type=metric_type, metric_name=name, metric_value=round(float(value), 4), **where)

    results = [entry("success_rate", f"success rate, {_rate(success)}", success["success_rate"])]
    if "success_with_ground_truth_goals" in metrics:
        upper = metrics["success_with_ground_truth_goals"]
        results.append(
            entry(
                "success_rate_ground_truth_goals",
                f"success rate with ground-truth goals, {_rate(upper)}",
                upper["success_rate"],
            )
        )
    results += [entry(kind, name, metrics[key]["median"]) for key, (kind, name) in _MEDIANS.items() if key in metrics]
    results += [entry(kind, name, metrics[key]) for key, (kind, name) in _VALUES.items() if key in metrics]
    threshold = (
        f"{metrics['coverage_threshold_mm']} mm"
        if "coverage_threshold_mm" in metrics
        else f"{metrics.get('coverage_threshold')} RMSE"
    )
    results += [
        entry(key.replace("@", "_at_"), f"{key} (threshold {threshold})", value)
        for key, value in metrics.items()
        if key.startswith(("coverage@", "precision@"))
    ]
    return results


def _example(config, metrics: dict) -> list[str]:
    """A runnable snippet: the checkpoint by name (Hub id, or the package's shipped name) on a held-out
    scene of its task; without a known task, on the user's own clouds."""
    task = metrics.get("task")
    name = config.repo_id or task or "path/to/pretrained_model"
    if task == CLOTH_TASK:
        scene = [
            "from lerobot_taxdpd.sim.cloth.env import ClothHangEnv",
            "",
            'observation, _ = ClothHangEnv("test").reset(seed=0)             # a held-out cloth scene',
            f'object_points = torch.from_numpy(observation["{OBJECT_KEY}"])[None]   # (1, N_O, 3)',
            f'scene_points = torch.from_numpy(observation["{SCENE_KEY}"])[None]     # (1, N_S, 3)',
        ]
    elif task:
        scene = [
            "from lerobot_taxdpd.sim.tasks import get_task",
            "from lerobot_taxdpd.sim.trials import make_trial",
            "",
            f'trial = make_trial(get_task("{task}"), seed=0, split="test")   # a held-out simulated scene',
            "object_points = torch.from_numpy(trial.object_points)[None]   # (1, N_O, 3), metres",
            "scene_points = torch.from_numpy(trial.scene_points)[None]     # (1, N_S, 3), metres",
        ]
    else:
        scene = ["# object_points (B, N_O, 3) and scene_points (B, N_S, 3): your segmented clouds, in metres"]
    lines = [
        "```python",
        "import torch",
        "from lerobot_taxdpd import load_goal_predictor",
        *scene,
        "",
        f'policy = load_goal_predictor("{name}")  # a shipped name, Hub id or folder; device="cuda" for a GPU',
        "goals = policy.sample_goals(object_points, scene_points, num_samples=10)   # (B, 10, N_O, 3), metres",
    ]
    if task != CLOTH_TASK:
        lines.append("poses = policy.predict_poses(object_points, scene_points, num_samples=10)  # (B, 10, 4, 4)")
    if config.use_gmm:
        lines.append("weights, means = policy.placement_distribution(object_points, scene_points)  # Dense GMM")
    return [*lines, "```"]


def _orientation(metrics: dict) -> list[str]:
    """Whether the goal's orientation is read off the scene or copied from the start (docs/taxdpd.md)."""
    lines = []
    turns = metrics.get("equivariance_deg")
    if turns:
        lines.append(
            f"- Orientation: turning the scene by {turns['angle']:.0f} deg turns the predicted goal by "
            f"{turns['scene_yaw']:.1f} deg (ideal {turns['angle']:.0f}); turning the object alone by "
            f"{turns['angle']:.0f} deg turns it by {turns['object_yaw']:.1f} deg, tilting it alone by "
            f"{turns['tilt_angle']:.0f} deg by {turns['object_tilt']:.1f} deg (ideal 0; a model that copies the "
            f"start orientation: the same angles), median over {turns['trials']} held-out scenes."
        )
    baselines = metrics.get("baselines_true_position")
    if baselines:
        copy, mean = baselines["copy_start_orientation"], baselines["mean_goal_orientation"]
        lines.append(
            f"- Trivial baselines at the true position, same trials: copying the start orientation "
            f"{copy['success_rate']:.0%} ({copy['rotation_error_deg_median']:.1f} deg), the mean goal "
            f"orientation {mean['success_rate']:.0%} ({mean['rotation_error_deg_median']:.1f} deg)."
        )
    copied = metrics.get("copy_start_goal_metrics")
    if copied:
        lines.append(
            f"- Trivial baseline, same scenes: the start cloth moved to the goal's centroid, shape and orientation "
            f"copied, has coverage / precision RMSE {copied['coverage_rmse']:.2f} / {copied['precision_rmse']:.2f}."
        )
    return lines


def _limitations(config, metrics: dict) -> list[str]:
    lines = ["## Limitations", ""]
    radius = config.object_scale / config.point_scale if config.point_scale else None
    if metrics.get("success"):
        executed = f"{metrics.get('goal_selection', 'first')} sample executed"
        if "success_with_ground_truth_goals" in metrics:
            executed += " by gc_dp3"
        lines.append(
            f"- Measured in simulation only, on held-out geometry (see Training and evaluation): success "
            f"{_rate(metrics['success'])}, {executed}."
        )
        by_rule = metrics.get("success_by_selection")
        if by_rule:
            chosen = ", ".join(f"{rule} {_rate(rate)}" for rule, rate in by_rule.items())
            lines.append(f"  The same samples, chosen by another rule and executed alike: {chosen}.")
        if "success_with_ground_truth_goals" in metrics:
            lines.append(
                f"  With ground-truth goals the same executor reaches "
                f"{_rate(metrics['success_with_ground_truth_goals'])}: the upper bound of this pipeline."
            )
        errors = [
            f"{name.replace('median ', '')} {metrics[key]['median']:.1f}"
            for key, (_, name) in _MEDIANS.items()
            if key in metrics and key != "rmse_mm"
        ]
        if errors:
            lines.append(f"- Median errors on those trials: {'; '.join(errors)}.")
        quality = [
            f"{key} {value:.2f}"
            for key, value in metrics.items()
            if key.startswith(("coverage", "precision")) and "threshold" not in key
        ]
        if quality:
            lines.append(f"- Multi-modal quality: {', '.join(quality)}.")
    lines += _orientation(metrics)
    if metrics.get("training_steps"):
        lines.append(
            f"- A CPU budget: {metrics['training_steps']} steps at batch {metrics.get('batch_size')}, far from "
            "the paper's GPU-scale training: use it to try the pipeline, not as a reproduction of the paper's "
            "numbers."
        )
    lines.append(
        "- Trained on procedural pybullet scenes (partial-view clouds from simulated depth cameras); real "
        "sensors, other objects and other scenes are out of distribution."
    )
    if radius:
        lines.append(
            f"- Inputs in metres, as in training (median object radius {radius:.3g} m): objects over 10x "
            "larger or smaller raise a warning (millimetres for metres is 1000x)."
        )
    return lines


def render_model_card(config, metrics: dict, dataset_repo_id: str | None, license, tags) -> ModelCard:
    """The card: title with the task, install line, runnable example, limitations, configuration, metrics."""
    task = metrics.get("task")
    title = (
        f"TAX-DPD goal predictor for `{task}`: {metrics.get('description', task)}"
        if task
        else ("TAX-DPD goal predictor")
    )
    data = card_data(
        "taxdpd",
        license,
        tags,
        dataset_repo_id,
        model_name=f"taxdpd-{task}" if task else "taxdpd",
        eval_results=eval_results(metrics),
        extra_tags=("placement",),
    )
    inputs = {
        key: tuple(config.input_features[key].shape) for key in (OBJECT_KEY, SCENE_KEY) if key in config.input_features
    }
    body = [
        f"# {title}",
        "",
        "Predicts where every point of a segmented object must go to be placed in a scene: a Dense GMM over",
        "scene points picks a placement frame, then a disentangled (frame + shape) point-cloud diffusion refines",
        "the goal cloud; RANSAC-SVD turns it into an SE(3) pose for rigid objects. Policy type `taxdpd` of the",
        '`lerobot_policy_taxdpd` plugin for LeRobot (He et al., "Disentangled Point Diffusion for Precise Object',
        'Placement", ICRA 2026; an independent implementation).',
        "",
        *([f"Training data: `{dataset_repo_id}`"] if dataset_repo_id else []),
        *([f"Inputs (points per cloud): {inputs}", ""] if inputs else []),
        "## Use",
        "",
        "```bash",
        INSTALL,
        "```",
        "",
        *_example(config, metrics),
        "",
        *_limitations(config, metrics),
        "",
        "## Configuration",
        "",
        *config_table(config, _SWITCHES + _SHAPE + _SAMPLING + _TRAINING),
    ]
    if metrics.get("training_command"):
        body += ["", "## Training and evaluation", ""]
        if metrics.get("data"):
            body.append(f"- data: {metrics['data']}")
        body.append(f"- trained with `{metrics['training_command']}`")
        origin = metrics.get("initialised_from")
        if origin:
            body.append(
                f"- starting from the weights of `{origin['name']}` as they were then (weights {origin['weights']}), "
                f"trained with `{origin.get('training_command', 'unrecorded')}`"
            )
        if metrics.get("evaluation"):
            body.append(
                f"- evaluated on {metrics['evaluation']}; the numbers are in the card's metadata and in `metrics.json`"
            )
    features = {
        "input_features": {k: list(v.shape) for k, v in config.input_features.items()},
        "output_features": {k: list(v.shape) for k, v in config.output_features.items()},
    }
    body += [
        "",
        "<details><summary>Features</summary>",
        "",
        "```json",
        json.dumps(features, indent=2),
        "```",
        "",
        "</details>",
    ]
    return assemble(data, body)
