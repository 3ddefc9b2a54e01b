"""The model card written beside every saved `gc_dp3` checkpoint and pushed with it to the Hub (LeRobot's
generic card names no plugin policy and shows another policy's commands)."""

from __future__ import annotations

from huggingface_hub import ModelCard

from lerobot_taxdpd.policies.model_cards import INSTALL, assemble, card_data, config_table

_SHAPE = (
    "n_obs_steps",
    "horizon",
    "n_action_steps",
    "cloud_keys",
    "points_per_cloud",
    "point_encoder_dims",
    "point_feature_dim",
    "down_dims",
    "num_inference_steps",
)


def render_model_card(config, metrics: dict, dataset_repo_id: str | None, license, tags) -> ModelCard:
    """What the policy does, how to install, load and evaluate it, what it measured, its limits and its
    configuration."""
    # A shipped executor is loaded by its task's name; a Hub or local checkpoint by its folder.
    shipped = metrics.get("task")
    folder = shipped or ("gc_dp3_checkpoint" if config.repo_id else "path/to/pretrained_model")
    download = [f"hf download {config.repo_id} --local-dir {folder}"] if config.repo_id and not shipped else []
    data = card_data("gc_dp3", license, tags, dataset_repo_id, model_name="gc_dp3", extra_tags=("cloth", "dp3"))
    body = [
        "# gc_dp3: goal-conditioned 3D Diffusion Policy for cloth hanging",
        "",
        "DP3 (Ze et al., 2024) whose point input also holds a goal cloud: the cloth, the hangers and where the",
        "cloth must end up, each tagged with its segment, drive a 1-D U-Net that denoises chunks of both",
        "grippers' position deltas. Trained on ground-truth goals; at run time the goal comes from a TAX-DPD",
        "goal predictor (policy type `taxdpd`). Policy type `gc_dp3` of the `lerobot_policy_taxdpd` plugin.",
        "",
        *([f"Training data: `{dataset_repo_id}`", ""] if dataset_repo_id else []),
        "## Use",
        "",
        "```bash",
        INSTALL,
        *download,
        "# held-out cloth scenes, goals from the shipped goal predictor, executed by this policy:",
        f"python -m lerobot_taxdpd.sim eval --task cloth_hang --policy.path {folder} --goal-policy.path cloth_hang "
        "--trials 20",
        "```",
        "",
        "```python",
        "from lerobot_taxdpd.sim.cloth.evaluation import load_gc_dp3",
        "",
        f'policy, preprocessor, postprocessor = load_gc_dp3("{folder}", device="cpu")',
        "# per control step: {cloth, hangers, goal cloud, 12-d gripper state} -> 6-d gripper deltas (metres)",
        "```",
        "",
        *_measured(metrics),
        "## Limitations",
        "",
        "- Trained and evaluated on the package's procedural pybullet cloth task only (complete mesh samples,",
        "  not depth-camera views); its success with ground-truth goals bounds what predicted goals reach",
        "  (`sim eval --task cloth_hang --ground-truth-goals`).",
        "- The default size is far below DP3's (about 5M against 255M parameters) for CPU training.",
        "",
        "## Configuration",
        "",
        *config_table(config, _SHAPE),
    ]
    return assemble(data, body)


def _measured(metrics: dict) -> list[str]:
    """The shipped executor's held-out success with ground-truth and predicted goals, with how it was trained."""
    if not metrics:
        return []
    lines = ["## Measured", ""]
    for key, label in (("success_with_ground_truth_goals", "ground-truth goals"), ("success", "predicted goals")):
        if key in metrics:
            rate = metrics[key]
            lines.append(
                f"- success with {label}: {rate['success_rate']:.2f} (95% CI {rate['ci95_low']:.2f}-"
                f"{rate['ci95_high']:.2f}) over {rate['trials']} held-out scenes"
            )
    for key in ("evaluation", "data", "training_command", "training_steps"):
        if key in metrics:
            lines.append(f"- {key.replace('_', ' ')}: {metrics[key]}")
    return [*lines, ""]
