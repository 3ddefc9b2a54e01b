"""TAX-DPD goal prediction for LeRobot: Dense GMM + disentangled point-cloud diffusion.

Importing the package registers the `taxdpd` and `gc_dp3` policy types (configs and processor steps)
with LeRobot.
Modeling classes load lazily, so `import lerobot_taxdpd` stays cheap for LeRobot's plugin discovery.
"""

from importlib import import_module

from lerobot_taxdpd.policies.gc_dp3.configuration_gc_dp3 import GcDp3Config
from lerobot_taxdpd.policies.gc_dp3.processor_gc_dp3 import make_gc_dp3_pre_post_processors
from lerobot_taxdpd.policies.taxdpd.configuration_taxdpd import TaxDPDConfig
from lerobot_taxdpd.policies.taxdpd.processor_taxdpd import make_taxdpd_pre_post_processors
from lerobot_taxdpd.sim import env_config as _sim_env_config  # noqa: F401  (registers --env.type=taxdpd_sim)

__version__ = "0.1.0"

_LAZY = {
    "TaxDPDPolicy": "lerobot_taxdpd.policies.taxdpd.modeling_taxdpd",
    "GcDp3Policy": "lerobot_taxdpd.policies.gc_dp3.modeling_gc_dp3",
    "load_goal_predictor": "lerobot_taxdpd.goal_predictors",
    "list_goal_predictors": "lerobot_taxdpd.goal_predictors",
}

__all__ = [
    "GcDp3Config",
    "TaxDPDConfig",
    "make_gc_dp3_pre_post_processors",
    "make_taxdpd_pre_post_processors",
    *_LAZY,
]


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'lerobot_taxdpd' has no attribute {name!r}")
