"""Installing this plugin must never break LeRobot's own command lines, for our policy types or any other.

draccus turns the comment beside every config field into argparse help text, where `%` is a format
character: one "5% of" in a comment once made `lerobot-train --help` crash for every policy type.
"""

from __future__ import annotations

import dataclasses

import pytest
from draccus.wrappers.docstring import get_attribute_docstring

from conftest import run_cli
from lerobot_taxdpd import GcDp3Config, TaxDPDConfig
from lerobot_taxdpd.sim.env_config import TaxDPDSimEnvConfig


# draccus prints every registered type's fields whichever type is named, so one command per LeRobot script
# renders what the bare `--help` and every other type would (each command takes about 10 s).
@pytest.mark.parametrize(
    ("command", "shown"),
    [
        (
            ["lerobot-train", "--policy.type=taxdpd", "--help"],
            ["--policy.type", "--policy.ransac_threshold", "--policy.point_feature_dim"],  # both plugin policies
        ),
        (
            ["lerobot-eval", "--env.type=taxdpd_sim", "--help"],
            ["--env.type", "--env.split", "--policy.ransac_threshold"],
        ),
    ],
)
def test_lerobot_help_works_with_the_plugin_installed(command, shown):
    result = run_cli(*command, timeout=300)
    for option in shown:
        assert option in result.stdout
    assert "taxdpd" in result.stdout  # the plugin's types are offered


@pytest.mark.parametrize("config_class", [TaxDPDConfig, GcDp3Config, TaxDPDSimEnvConfig])
def test_no_config_field_help_holds_a_bare_percent_sign(config_class):
    for field in dataclasses.fields(config_class):
        doc = get_attribute_docstring(config_class, field.name)
        for text in (doc.comment_above, doc.comment_inline, doc.docstring_below):
            assert "%" not in text.replace("%%", ""), f"{config_class.__name__}.{field.name}: {text!r}"
