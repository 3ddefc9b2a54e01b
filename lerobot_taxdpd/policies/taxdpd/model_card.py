"""The model card written beside every saved `taxdpd` checkpoint and pushed with it to the Hub."""

from __future__ import annotations

import json

from lerobot_taxdpd.data.schema import OBJECT_KEY, SCENE_KEY

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
_SAMPLING = ("sampler", "num_inference_steps", "num_train_timesteps")


def _rows(config, names) -> list[str]:
    return [f"| `{name}` | `{getattr(config, name)}` |" for name in names]


def _metric_rows(metrics: dict, prefix: str = "") -> list[str]:
    rows = []
    for key, value in metrics.items():
        if isinstance(value, dict):
            rows += _metric_rows(value, f"{prefix}{key}.")
        elif isinstance(value, float):
            rows.append(f"| {prefix}{key} | {value:.4g} |")
        else:
            rows.append(f"| {prefix}{key} | {value} |")
    return rows


def render_model_card(card_yaml: str, config, metrics: dict, dataset_repo_id: str | None) -> str:
    """Markdown with front matter: what the model is, how to load it, its configuration and its metrics."""
    inputs = {
        key: tuple(config.input_features[key].shape) for key in (OBJECT_KEY, SCENE_KEY) if key in config.input_features
    }
    lines = [
        "---",
        card_yaml.strip(),
        "---",
        "",
        "# TAX-DPD goal predictor",
        "",
        "Predicts where every point of a segmented object must go to be placed in a scene: a Dense GMM over",
        "scene points picks a placement frame, then a disentangled (frame + shape) point-cloud diffusion refines",
        "the goal cloud; RANSAC-SVD turns it into an SE(3) pose for rigid objects. Policy type `taxdpd` of the",
        "`lerobot_policy_taxdpd` plugin for LeRobot.",
        "",
        f"Training data: `{dataset_repo_id}`" if dataset_repo_id else "",
        f"Inputs: {inputs}" if inputs else "",
        "",
        "```python",
        "from lerobot_taxdpd import TaxDPDPolicy",
        'policy = TaxDPDPolicy.from_pretrained("<this repo id or folder>")',
        "goals = policy.sample_goals(object_points, scene_points, num_samples=10)  # (B, 10, N_O, 3), metres",
        "poses = policy.predict_poses(object_points, scene_points, num_samples=10)  # (B, 10, 4, 4)",
        "```",
        "",
        "## Configuration",
        "",
        "| setting | value |",
        "|---|---|",
        *_rows(config, _SWITCHES + _SHAPE + _SAMPLING),
    ]
    if metrics:
        lines += ["", "## Metrics", "", "| metric | value |", "|---|---|", *_metric_rows(metrics)]
    features = {
        "input_features": {k: list(v.shape) for k, v in config.input_features.items()},
        "output_features": {k: list(v.shape) for k, v in config.output_features.items()},
    }
    lines += [
        "",
        "<details><summary>Features</summary>",
        "",
        "```json",
        json.dumps(features, indent=2),
        "```",
        "",
        "</details>",
        "",
    ]
    return "\n".join(lines)
