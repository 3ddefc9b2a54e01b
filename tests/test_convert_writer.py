"""The shared DatasetWriter as the converters rely on it: a failure while creating leaves nothing behind."""

from __future__ import annotations

import pytest

from convert_fixtures import leftovers
from lerobot_taxdpd.data.dataset_writer import DatasetCardInfo, DatasetWriter


def test_failure_inside_create_removes_the_partial_folder(tmp_path):
    root = tmp_path / "out"
    bad_features = {"observation/cloud": {"dtype": "float32", "shape": (4, 3), "names": None}}  # '/' is refused
    with pytest.raises(ValueError, match="should not contain '/'"):
        with DatasetWriter("local/x", root, bad_features, fps=10, card=DatasetCardInfo("test", "none")):
            pass
    assert not root.exists() and leftovers(root) == []
