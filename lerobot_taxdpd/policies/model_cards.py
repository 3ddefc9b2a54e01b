"""What every model card of this package shares: the install line, the card data of a LeRobot policy, the
configuration table and the assembled card (huggingface_hub's own classes, so the Hub reads the metadata)."""

from __future__ import annotations

from huggingface_hub import EvalResult, ModelCard, ModelCardData

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
