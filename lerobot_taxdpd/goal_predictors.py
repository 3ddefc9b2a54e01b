"""Goal predictors by name: the small checkpoints shipped inside the package first, then folders and Hub ids.

A shipped predictor is a `lerobot_taxdpd/pretrained/<name>/` folder written by `save_pretrained` (config,
safetensors weights, model card, `metrics.json` with its measured success, processors), so a name works
offline on a fresh install. Anything else is handed to `TaxDPDPolicy.from_pretrained`: a local checkpoint
folder, or a Hub repo id resolved by huggingface_hub (its cache and `HF_HUB_OFFLINE=1` are respected).

A task whose goals are executed by a learnt policy (cloth_hang) ships that `gc_dp3` executor under the same
name, in `pretrained/<name>/executor/`: `resolve_executor("cloth_hang")` finds it, so one name gives the
whole pipeline. A goal scorer trained on a predictor's executed samples (`lerobot_taxdpd.scoring`) ships in
`pretrained/<name>/scorer/`, so `--goal-selection scorer` finds it by the same name.

    python -m lerobot_taxdpd.goal_predictors list                    # names, tasks and measured metrics
    python -m lerobot_taxdpd.goal_predictors path mug_easyrack       # a folder for `--goal-policy.path=...`
    python -m lerobot_taxdpd.goal_predictors path cloth_hang --executor  # a folder for `--policy.path=...`
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

from lerobot_taxdpd.data.schema import METRICS_FILE

SHIPPED_DIR = Path(__file__).parent / "pretrained"
#: Where a shipped name keeps its gc_dp3 executor, if its task has one.
EXECUTOR_DIR = "executor"
#: Where a shipped name keeps the goal scorer trained on its samples, if it has one.
SCORER_DIR = "scorer"


def _shipped() -> dict[str, Path]:
    if not SHIPPED_DIR.is_dir():
        return {}
    return {p.name: p for p in sorted(SHIPPED_DIR.iterdir()) if (p / "config.json").is_file()}


def has_placement_distribution(predictor: object) -> bool:
    """Whether `predictor` has a Dense GMM to query: a TAX-DPD model trained with `use_gmm=false` keeps the
    `placement_distribution` method but has no GMM behind it."""
    config = getattr(predictor, "config", None)
    return hasattr(predictor, "placement_distribution") and getattr(config, "use_gmm", True)


def list_goal_predictors() -> dict[str, dict]:
    """Shipped names -> their `metrics.json` (task, training command, held-out success, errors)."""
    listing = {}
    for name, folder in _shipped().items():
        metrics = folder / METRICS_FILE
        listing[name] = json.loads(metrics.read_text()) if metrics.is_file() else {}
    return listing


def resolve_goal_predictor(name_or_path: str | Path) -> str:
    """A shipped name, an existing folder, or a Hub repo id ('owner/name') -> what `from_pretrained` takes."""
    return _resolve(name_or_path, _shipped(), "goal predictor", "taxdpd")


def _shipped_beside(subdir: str) -> dict[str, Path]:
    """Shipped names that keep a checkpoint in `<name>/<subdir>/` -> that folder."""
    return {name: folder / subdir for name, folder in _shipped().items() if (folder / subdir / "config.json").is_file()}


def shipped_executors() -> dict[str, Path]:
    """Shipped names that come with a gc_dp3 executor -> its folder."""
    return _shipped_beside(EXECUTOR_DIR)


def resolve_executor(name_or_path: str | Path) -> str:
    """A shipped name with an executor, an existing folder, or a Hub repo id -> what gc_dp3 loads."""
    return _resolve(name_or_path, shipped_executors(), "executor", "gc_dp3")


def weights_digest(checkpoint: str | Path) -> str:
    """A short hash of a checkpoint's weights: a scorer learns one goal predictor's mistakes."""
    weights = Path(checkpoint) / "model.safetensors"
    return hashlib.sha256(weights.read_bytes()).hexdigest()[:16] if weights.is_file() else "unknown"


def shipped_scorers() -> dict[str, Path]:
    """Shipped names that come with a goal scorer -> its folder."""
    return _shipped_beside(SCORER_DIR)


def resolve_scorer(name_or_path: str | Path) -> str:
    """A shipped name that has a scorer, an existing scorer folder, or a Hub repo id -> what `load_scorer` takes."""
    return _resolve(name_or_path, shipped_scorers(), "goal scorer", "goal scorer")


def load_scorer(name_or_path: str | Path):
    """A `GoalScorer` (eval mode) for a shipped name that has one, a scorer folder or a Hub repo id."""
    from lerobot_taxdpd.policies.goal_scorer import GoalScorer

    source = resolve_scorer(name_or_path)
    try:
        return GoalScorer.from_pretrained(source).eval()
    except OSError as error:
        if Path(source).is_dir():
            raise
        raise FileNotFoundError(_hub_failure(source).replace("goal predictor", "goal scorer")) from error


def _resolve(name_or_path: str | Path, shipped: dict[str, Path], kind: str, policy_type: str) -> str:
    text = str(name_or_path)
    if text in shipped:
        return str(shipped[text])
    path = Path(text).expanduser()
    if path.is_dir():
        if not (path / "config.json").is_file():
            raise FileNotFoundError(
                f"{path}: not a {policy_type} checkpoint (no config.json)"
                + ("; pass its pretrained_model folder" if policy_type in ("taxdpd", "gc_dp3") else "")
            )
        return str(path)
    parts = text.split("/")
    if len(parts) == 2 and all(parts):
        return text
    known = ", ".join(shipped) or f"none (this install ships no {kind}s)"
    raise ValueError(
        f"unknown {kind} {text!r}: not a shipped name, a checkpoint folder or a Hub repo id "
        f"'owner/name'; shipped names: {known}"
    )


def load_goal_predictor(name_or_path: str | Path, device: str | None = None, **kwargs):
    """A ready `TaxDPDPolicy` (eval mode) for a shipped name, a checkpoint folder or a Hub repo id.

    `device` ("cpu", "cuda", "cuda:1", ...) is where the weights load and the sampling runs (default: the
    checkpoint's own, "cpu" for the shipped ones); `kwargs` go to `from_pretrained` (revision, cache_dir, ...).
    """
    from lerobot_taxdpd.policies.checkpoints import read_config
    from lerobot_taxdpd.policies.taxdpd.modeling_taxdpd import TaxDPDPolicy

    source = resolve_goal_predictor(name_or_path)
    if device is not None:
        check_device(device)
    try:
        if device is not None:
            hub_kwargs = {key: kwargs[key] for key in ("revision", "cache_dir", "force_download") if key in kwargs}
            kwargs["config"] = read_config(source, **hub_kwargs)
            kwargs["config"].device = device
        policy = TaxDPDPolicy.from_pretrained(source, **kwargs)
    except OSError as error:
        if Path(source).is_dir():
            raise
        raise FileNotFoundError(_hub_failure(source)) from error
    return policy.eval()


def check_device(device: str) -> None:
    """Refuse, naming `device`, what torch cannot parse or this machine lacks (a CUDA name on a CUDA-less
    machine, an index past the last GPU): otherwise the failure comes later, deep in loading or sampling."""
    import torch

    if not isinstance(device, (str, torch.device)):
        raise TypeError(f"device: expected a string such as 'cpu' or 'cuda:0', got {type(device).__name__}")
    try:
        parsed = torch.device(device)
    except RuntimeError as error:
        raise ValueError(f"device: {device!r} is not a torch device name (try 'cpu' or 'cuda')") from error
    counts = {
        "cpu": lambda: 1,
        "cuda": torch.cuda.device_count,
        "mps": lambda: int(torch.backends.mps.is_available()),
        "xpu": lambda: torch.xpu.device_count() if torch.xpu.is_available() else 0,
    }
    available = counts[parsed.type]() if parsed.type in counts else 0
    if (parsed.index or 0) >= available:
        raise ValueError(f"device: {device!r} is not available on this machine (try 'cpu')")


def _hub_failure(repo_id: str) -> str:
    """Why a Hub id did not load, told apart for offline mode (nothing cached) and online failures."""
    from huggingface_hub import constants

    if constants.HF_HUB_OFFLINE:
        return (
            f"goal predictor {repo_id!r}: HF_HUB_OFFLINE is set and it is not in the local Hugging Face cache "
            f"({constants.HF_HUB_CACHE}). Download it once with network access (`hf download {repo_id}`, or load "
            "it once without HF_HUB_OFFLINE), or pass a checkpoint folder or a shipped name "
            f"({', '.join(_shipped()) or 'none in this install'})."
        )
    return (
        f"goal predictor {repo_id!r}: not found on the Hugging Face Hub nor in the local cache. Check the id; "
        "a private repository needs `hf auth login` (or HF_TOKEN); without network access, download it "
        f"elsewhere with `hf download {repo_id}` and copy the cache ({constants.HF_HUB_CACHE})."
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m lerobot_taxdpd.goal_predictors", description=__doc__.split("\n\n")[0]
    )
    verbs = parser.add_subparsers(dest="verb", required=True)
    verbs.add_parser("list", help="shipped names with their measured metrics")
    path = verbs.add_parser("path", help="the checkpoint folder or Hub id a name resolves to")
    path.add_argument("name")
    path.add_argument("--executor", action="store_true", help="the name's gc_dp3 executor instead (cloth_hang)")
    args = parser.parse_args(argv)
    if args.verb == "path":
        try:
            print(resolve_executor(args.name) if args.executor else resolve_goal_predictor(args.name))
        except (ValueError, FileNotFoundError) as error:
            print(f"error: {error}", file=sys.stderr)
            return 1
        return 0
    with_executor = shipped_executors()
    for name, metrics in list_goal_predictors().items():
        success = metrics.get("success", {})
        figures = (
            f"success {success['success_rate']:.0%} over {success['trials']} held-out trials"
            if success
            else "not evaluated"
        )
        executor = " (+ gc_dp3 executor)" if name in with_executor else ""
        print(f"{name:<20} {figures:<40} {metrics.get('description', '')}{executor}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
