"""The scorer's search settings as command-line options, shared by `scoring train`, `scoring ship` and `sim eval`.

A scorer carries its search in its config (chosen per task, shipped with it); these options set it when a
scorer is trained, and override it where one is measured or shipped.
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the options stay importable without torch, so that `--help` is quick
    from lerobot_taxdpd.policies.goal_scorer import GoalScorerConfig


def add_search_arguments(parser: argparse.ArgumentParser, prefix: str = "--") -> None:
    """`{prefix}search-extent-mm` and `{prefix}search-step-mm`, left unset (None) unless given."""
    parser.add_argument(
        f"{prefix}search-extent-mm",
        dest="search_extent_mm",
        type=float,
        default=None,
        metavar="MM",
        help="also try every sample shifted on a horizontal grid up to this far along x and y, and execute the "
        "best-rated copy (0: choose among the samples as sampled; default: the scorer's own setting)",
    )
    parser.add_argument(
        f"{prefix}search-step-mm",
        dest="search_step_mm",
        type=float,
        default=None,
        metavar="MM",
        help="that grid's spacing (default: the scorer's own)",
    )


def with_search(config: GoalScorerConfig, args: argparse.Namespace) -> GoalScorerConfig:
    """`config` with the search options given in `args` (those left unset keep the config's), checked."""
    given = {
        name: getattr(args, name)
        for name in ("search_extent_mm", "search_step_mm")
        if getattr(args, name, None) is not None
    }
    config = dataclasses.replace(config, **given)
    if config.search_extent_mm < 0 or config.search_step_mm <= 0:
        raise ValueError(
            f"--search-extent-mm must be >= 0 and --search-step-mm > 0, got {config.search_extent_mm} and "
            f"{config.search_step_mm}"
        )
    return config
