"""Converters from published demo formats into TAX-DPD LeRobot v3.0 datasets.

One module per source (`rpdiff`, `dedo`, `nist`), one CLI: `taxdpd-convert {rpdiff,dedo,nist,push,samples}` or
`python -m datasets_conv ...`; `samples` writes a few raw demos of every layout (`datasets_conv.samples`).
Every converter writes through `lerobot_taxdpd.data.dataset_writer.DatasetWriter`, so a failed or
interrupted run never leaves a partial dataset behind. Names load lazily, so the CLI's
`--help` does not wait for LeRobot and torch to import.
"""

from importlib import import_module

_LAZY = {
    "ConversionOptions": "datasets_conv.pipeline",
    "ConversionSummary": "datasets_conv.pipeline",
    "RPDIFF_TASKS": "datasets_conv.rpdiff",
    "convert_rpdiff": "datasets_conv.rpdiff",
    "convert_dedo_goals": "datasets_conv.dedo",
    "convert_dedo_rollouts": "datasets_conv.dedo",
    "convert_nist": "datasets_conv.nist",
}

__all__ = list(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'datasets_conv' has no attribute {name!r}")
