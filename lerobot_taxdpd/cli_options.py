"""Old spellings of renamed command-line options: still accepted, hidden from `--help`, and named in a warning.

The package's commands share one vocabulary (`--frames-per-episode`, `--figures`, `--goal-policy.path` for a
goal predictor and `--policy.path` for an executor); scripts written against the old names keep working.
"""

from __future__ import annotations

import argparse
import sys


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
