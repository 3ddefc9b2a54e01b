"""Discovery shim: LeRobot 0.4.4 imports installed distributions named `lerobot_policy_*`.

Importing this module registers the `taxdpd` and `gc_dp3` policy types (and the package's
simulation envs) with LeRobot's config registries. Nothing else lives here.
"""

import lerobot_taxdpd  # noqa: F401
