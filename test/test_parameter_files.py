"""Every node parameter is in its config/<node>.yaml (set, or shown commented out where
its default is an empty list), so the shipped files show every knob (issue 26)."""
import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize('node', ['gps_ingest', 'estimator', 'controller', 'fleet_sim'])
def test_every_parameter_is_in_the_config_file(node):
    names = set(importlib.import_module(f'herd_ros.nodes.{node}').DEFAULTS)
    text = (ROOT / 'config' / f'{node}.yaml').read_text()
    shown = set(re.findall(r'^\s+(?:#\s*)?([a-z_0-9]+):', text, re.M))
    assert not names - shown, f'config/{node}.yaml lacks {sorted(names - shown)}'
