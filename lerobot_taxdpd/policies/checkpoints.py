"""Loading a damaged, edited or foreign checkpoint fails once, with the file and what is wrong.

LeRobot 0.4.4 loads weights with `strict=False` and only logs missing or unexpected tensors, so a truncated
or edited `model.safetensors` would give a policy that samples from random weights; its config errors name a
field but not the file, and a checkpoint of another policy type fails deep in the constructor. The mixin
below reads `config.json` and `model.safetensors` strictly (JSON and safetensors only: nothing is unpickled)
for every path into a policy: `from_pretrained`, names and folders, `lerobot-eval`, fine-tuning and resuming.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from draccus.utils import ParsingError
from huggingface_hub import hf_hub_download
from lerobot.configs.policies import PreTrainedConfig
from safetensors import SafetensorError
from safetensors.torch import load_file

CONFIG_FILE = "config.json"
#: Tensors of the weight average (policies/ema.py): a checkpoint saved without one still loads into a policy
#: that keeps one, whose average then starts at the loaded weights (fine-tuning a shipped model with EMA on).
EMA_PREFIXES = ("ema_model.", "ema_step")
#: policy type -> what fields added after a checkpoint was first shipped did before they existed. A config.json
#: saved without such a field is read with this value, not with today's default: a goal predictor trained when
#: the denoiser always predicted the noise must keep sampling that way (docs/taxdpd.md#learning-orientation).
LEGACY_VALUES = {"taxdpd": {"prediction_type": "epsilon", "rotation_noise": "paper"}}
HUB_KWARGS = ("force_download", "resume_download", "proxies", "token", "cache_dir", "local_files_only", "revision")


class CheckpointError(ValueError):
    """A checkpoint that cannot be loaded; the message names the file and what is wrong with it."""


def _chain(error: BaseException, limit: int = 200) -> str:
    """Every message of an exception chain, outer first: draccus wraps a config's own ValueError (the field
    at fault) in a generic one, and its outer messages say which field it was parsing."""
    messages = []
    while error is not None:
        text = str(error)
        messages.append(text if len(text) <= limit else text[:limit] + "...")
        error = error.__cause__ or error.__context__
    return "; ".join(dict.fromkeys(messages))


def read_config(pretrained_name_or_path, **kwargs) -> PreTrainedConfig:
    """`config.json` of a folder or Hub id, with decoding errors turned into a `CheckpointError` naming it."""
    where = Path(pretrained_name_or_path) / CONFIG_FILE
    try:
        return PreTrainedConfig.from_pretrained(pretrained_name_or_path, **kwargs)
    except (json.JSONDecodeError, ParsingError, ValueError, TypeError) as error:
        raise CheckpointError(f"{where}: not a valid policy config ({_chain(error)})") from error


def saved_fields(pretrained_name_or_path, **kwargs) -> set[str]:
    """The keys `config.json` really holds (draccus fills the others with today's defaults)."""
    folder = Path(pretrained_name_or_path)
    if folder.is_dir():
        path = folder / CONFIG_FILE
    else:
        hub = {key: kwargs[key] for key in ("revision", "cache_dir", "local_files_only") if key in kwargs}
        path = Path(hf_hub_download(str(pretrained_name_or_path), CONFIG_FILE, **hub))
    return set(json.loads(path.read_text()))


def apply_legacy_values(config: PreTrainedConfig, saved: set[str]) -> None:
    """Give the fields a config.json predates the values they had then (`LEGACY_VALUES`)."""
    for name, value in LEGACY_VALUES.get(config.type, {}).items():
        if name not in saved:
            setattr(config, name, value)


def read_weights(model_file: str | Path) -> dict[str, torch.Tensor]:
    """Every tensor of a safetensors file, or a `CheckpointError` for a missing, truncated or garbled one."""
    try:
        return load_file(model_file)
    except FileNotFoundError as error:
        raise CheckpointError(f"{model_file}: missing (a checkpoint keeps its weights here)") from error
    except (SafetensorError, OSError) as error:
        raise CheckpointError(
            f"{model_file}: not a readable safetensors file, truncated or altered ({error})"
        ) from error


def _listed(names: list[str]) -> str:
    shown = ", ".join(names[:5])
    return shown + (f" and {len(names) - 5} more" if len(names) > 5 else "")


def check_weights(
    model: torch.nn.Module, weights: dict[str, torch.Tensor], model_file: str | Path, may_lack: tuple[str, ...] = ()
) -> None:
    """Refuse weights that do not fit `model` name for name and shape, or that hold NaN or inf. Tensors whose
    names contain one of `may_lack` may be absent (modules the file's model did not have; see `CheckedLoading`)."""
    expected = model.state_dict()
    has_ema = any(name.startswith(EMA_PREFIXES) for name in weights)
    missing = [
        n
        for n in expected
        if n not in weights
        and (has_ema or not n.startswith(EMA_PREFIXES))
        and not any(fragment in n for fragment in may_lack)
    ]
    unexpected = [n for n in weights if n not in expected and not n.startswith(EMA_PREFIXES)]
    if missing or unexpected:
        raise CheckpointError(
            f"{model_file}: does not fit this {getattr(model, 'name', 'policy')} config (missing: "
            f"{_listed(missing) or 'none'}; unexpected: {_listed(unexpected) or 'none'}); "
            f"the file was altered, or config.json does not belong to it"
        )
    resized = [
        f"{n} {tuple(weights[n].shape)} for {tuple(expected[n].shape)}"
        for n in weights
        if n in expected and weights[n].shape != expected[n].shape
    ]
    if resized:
        raise CheckpointError(f"{model_file}: tensors of the wrong shape for config.json: {_listed(resized)}")
    broken = [n for n, t in weights.items() if t.is_floating_point() and not bool(torch.isfinite(t).all())]
    if broken:
        raise CheckpointError(f"{model_file}: NaN or infinite values in {_listed(broken)}")


class CheckedLoading:
    """Mixin for a `PreTrainedPolicy` (listed before it): strict, clear loading of config and weights.

    `ZERO_START_MODULES` (config field -> a fragment of its modules' tensor names) lists modules that a switch
    adds and that start as the model without them (zero-initialised outputs). A file whose own config.json has
    the switch off lacks them and loads into a policy with it on, which then starts as the file's model: fine-
    tuning a shipped predictor with the switch. A file saved with the switch on must hold them."""

    ZERO_START_MODULES: dict[str, str] = {}

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path, *, config: PreTrainedConfig | None = None, **kwargs):
        if config is None:
            hub = {key: kwargs[key] for key in HUB_KWARGS if key in kwargs}
            config = read_config(pretrained_name_or_path, **hub)
        if not isinstance(config, cls.config_class):
            raise CheckpointError(
                f"{Path(pretrained_name_or_path) / CONFIG_FILE}: a {config.type!r} checkpoint, not a {cls.name!r} "
                f"one (load it with its own policy class or command)"
            )
        apply_legacy_values(config, saved_fields(pretrained_name_or_path, **kwargs))
        return super().from_pretrained(pretrained_name_or_path, config=config, **kwargs)

    @classmethod
    def _load_as_safetensor(cls, model, model_file: str, map_location: str, strict: bool):
        weights = read_weights(model_file)
        check_weights(model, weights, model_file, cls._switched_off_in(model_file))
        model.load_state_dict(weights, strict=False)  # exact but for an average the file does not hold
        if getattr(model.config, "use_ema", False) and not any(n.startswith(EMA_PREFIXES) for n in weights):
            model.ema_model.load_state_dict(model.model.state_dict())
        return model.to(map_location)

    @classmethod
    def _switched_off_in(cls, model_file: str) -> tuple[str, ...]:
        """The `ZERO_START_MODULES` whose switch the config.json beside `model_file` has off (or predates)."""
        path = Path(model_file).parent / CONFIG_FILE
        saved = json.loads(path.read_text()) if path.is_file() else {}
        return tuple(fragment for field, fragment in cls.ZERO_START_MODULES.items() if not saved.get(field))
