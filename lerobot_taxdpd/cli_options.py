"""Command-line options the package's commands share.

The commands share one vocabulary (`--frames-per-episode`, `--figures`, `--goal-policy.path` for a goal
predictor and `--policy.path` for an executor). Old spellings of renamed options are still accepted, hidden
from `--help` and named in a warning, so scripts written against them keep working. The goal scorer's search
settings are options of `scoring train` and `scoring ship` and of `sim eval` (as `--scorer.search-...`): a
scorer carries its search in its config (chosen per task, shipped with it); the options set it when a scorer
is trained and override it where one is measured or shipped.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # importable without torch, so that `--help` stays quick
    from lerobot_taxdpd.policies.goal_scorer import GoalScorerConfig


class _DeprecatedAlias(argparse.Action):
    def __init__(self, option_strings, dest, new_name: str, **kwargs):
        self.new_name = new_name
        super().__init__(option_strings, dest, help=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"warning: {option_string} is deprecated, use {self.new_name}", file=sys.stderr)
        setattr(namespace, self.dest, values)


def add_deprecated_alias(parser: argparse.ArgumentParser, old: str, new: str, dest: str, **kwargs) -> None:
    """Accept `old` as a hidden alias of the option `new` (which stores into `dest`)."""
    parser.add_argument(old, dest=dest, action=_DeprecatedAlias, new_name=new, default=argparse.SUPPRESS, **kwargs)


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


def search_overrides(args: argparse.Namespace) -> dict[str, float]:
    """The search options given in `args` (those left unset are left out), checked before anything runs."""
    given = {
        name: getattr(args, name)
        for name in ("search_extent_mm", "search_step_mm")
        if getattr(args, name, None) is not None
    }
    if given.get("search_extent_mm", 0.0) < 0 or given.get("search_step_mm", 1.0) <= 0:
        raise ValueError(
            f"--search-extent-mm must be >= 0 and --search-step-mm > 0, got {args.search_extent_mm} and "
            f"{args.search_step_mm}"
        )
    return given


def with_search(config: GoalScorerConfig, args: argparse.Namespace) -> GoalScorerConfig:
    """`config` with the search options given in `args`; those left unset keep the config's."""
    return dataclasses.replace(config, **search_overrides(args))
