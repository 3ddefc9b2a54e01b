"""What every model card of this package shares: the install line, the card data of a LeRobot policy, the
configuration table and the assembled card (huggingface_hub's own classes, so the Hub reads the metadata),
and the measured metrics (`metrics.json`) a checkpoint carries beside its weights and card."""

from __future__ import annotations

import json
from pathlib import Path

from huggingface_hub import EvalResult, ModelCard, ModelCardData, hf_hub_download
from huggingface_hub.errors import EntryNotFoundError, LocalEntryNotFoundError

from lerobot_taxdpd.data.schema import METRICS_FILE

INSTALL = "pip install lerobot_policy_taxdpd   # or, in a clone of the project: pip install -e ."


def card_data(
    policy_type: str,
    license: str | None,
    tags: list[str] | None,
    dataset_repo_id: str | None,
    model_name: str,
    eval_results: list[EvalResult] | None = None,
    extra_tags: tuple[str, ...] = (),
) -> ModelCardData:
    """LeRobot's card data (library, pipeline tag, licence, tags, dataset) plus the model-index results."""
    return ModelCardData(
        license=license or "apache-2.0",
        library_name="lerobot",
        pipeline_tag="robotics",
        tags=sorted(set(tags or []) | {"robotics", "lerobot", policy_type, "point-cloud", *extra_tags}),
        model_name=model_name,
        datasets=dataset_repo_id,
        eval_results=eval_results or None,
    )


def config_table(config, names: tuple[str, ...]) -> list[str]:
    return ["| setting | value |", "|---|---|", *(f"| `{name}` | `{getattr(config, name)}` |" for name in names)]


def assemble(data: ModelCardData, body: list[str]) -> ModelCard:
    """Front matter (with the model index when `data` has results) and the markdown body."""
    return ModelCard("\n".join(["---", data.to_yaml(), "---", "", *body, ""]))


def save_metrics(metrics: dict, save_directory: str | Path) -> None:
    """Write `metrics.json` beside the weights, when the policy has measured metrics."""
    if metrics:
        (Path(save_directory) / METRICS_FILE).write_text(json.dumps(metrics, indent=2))


def load_metrics(pretrained_name_or_path, kwargs: dict) -> dict:
    """metrics.json beside the weights (local folder or Hub repo), or {} when there is none."""
    path = Path(pretrained_name_or_path) / METRICS_FILE
    if not Path(pretrained_name_or_path).is_dir():
        try:
            path = Path(
                hf_hub_download(
                    str(pretrained_name_or_path),
                    METRICS_FILE,
                    revision=kwargs.get("revision"),
                    cache_dir=kwargs.get("cache_dir"),
                    local_files_only=kwargs.get("local_files_only", False),
                )
            )
        except (EntryNotFoundError, LocalEntryNotFoundError, OSError):
            return {}
    return json.loads(path.read_text()) if path.exists() else {}
