"""One parameter table per node (issue 26): ``config/<node>.yaml`` is what the node's table
renders, every parameter the node declares is in its table, and the table's checks say no
to what its types, ranges and choices rule out."""
import math
from pathlib import Path

import pytest
import yaml

from herd_ros.params import NODES, Param, markdown_table, problem, render_yaml, table, yaml_value
from herd_ros.params.controller import FLOCKING_TABLE, HERDING_TABLE

ROOT = Path(__file__).resolve().parents[1]
TABLES = [table(n) for n in NODES] + [FLOCKING_TABLE, HERDING_TABLE]


@pytest.mark.parametrize('t', TABLES, ids=lambda t: t.config_file)
def test_config_file_is_what_the_table_renders(t):
    shipped = (ROOT / 'config' / t.config_file).read_text()
    assert shipped == render_yaml(t), (
        f'config/{t.config_file} differs from herd_ros/params/{t.node}.py: run '
        f'herd-ros params --write (or edit the table, not the file)')


@pytest.mark.parametrize('t', TABLES, ids=lambda t: t.config_file)
def test_config_file_sets_the_defaults(t):
    """Read back by a YAML parser, every entry not marked as an example is the default."""
    values = yaml.safe_load((ROOT / 'config' / t.config_file).read_text())
    values = values[t.node]['ros__parameters']
    for name, spec in t.params.items():
        if spec.commented:
            assert name not in values
        else:
            assert values[name] == spec.shown and type(values[name]) is type(spec.shown), name
            assert problem(spec, values[name]) is None, name


def test_every_declared_parameter_is_in_a_table():
    """The nodes declare their parameters from these tables (names of the modules' dicts)."""
    from herd_ros.nodes import (controller, estimator, fleet_sim, flocking_mode, gps_ingest,
                                herd_model_mode, herd_sim, herding_mode, record, replay)
    from herd_ros.params import controller as c
    for module, params in [(gps_ingest, table('gps_ingest').params),
                           (estimator, table('estimator').params),
                           (fleet_sim, table('fleet_sim').params),
                           (herd_sim, table('herd_sim').params),
                           (replay, table('replay').params), (record, table('record').params),
                           (controller, c.COMMON)]:
        assert module.DEFAULTS is params
    assert herd_model_mode.HERD_MODEL_DEFAULTS is c.HERD_MODEL
    assert flocking_mode.FLOCKING_DEFAULTS is c.FLOCKING
    assert herding_mode.HERDING_DEFAULTS is c.HERDING


def test_problem_checks_type_range_and_choices():
    number = Param(1.0, 'x', range=(0.0, 2.0))
    assert problem(number, 1) is None and problem(number, 2.0) is None
    assert 'within [0, 2]' in problem(number, 2.5)
    assert 'finite' in problem(number, math.nan) and 'finite' in problem(number, 'a')
    assert problem(number, True) is not None
    count = Param(3, 'n', range=(1, 10))
    assert problem(count, 1.5) is not None and problem(count, 0) is not None
    choice = Param('a', 'c', choices=('a', 'b'))
    assert problem(choice, 'b') is None and 'one of a, b' in problem(choice, 'c')
    assert problem(Param([], 'l'), [1, 2]) is None and problem(Param([], 'l'), 'x')


def test_yaml_values_read_back_as_their_type():
    for value in [1.0, 1e6, 1e-6, 0.1, 3, True, '', 'map', '/herd/poses', 'yes', "it's",
                  [1.0, 2.5], ['a', 'b'], [], -150.0]:
        text = yaml_value(value)
        back = yaml.safe_load(f'v: {text}')['v']
        assert back == value and type(back) is type(value), (value, text)


def test_markdown_table_lists_every_parameter():
    t = table('gps_ingest')
    text = markdown_table(t)
    assert all(f'| `{name}` |' in text for name in t.params)


def test_params_verb_writes_the_shipped_files_and_prints_a_table(tmp_path, capsys):
    from herd_ros.cli.main import main
    assert main(['params', '--write', str(tmp_path)]) == 0
    for t in TABLES:
        assert (tmp_path / t.config_file).read_text() == (ROOT / 'config' /
                                                          t.config_file).read_text()
    capsys.readouterr()
    assert main(['params', 'fleet_sim']) == 0
    out = capsys.readouterr().out
    assert '| `robots` |' in out and '| `cmd_timeout_s` |' in out
    assert main(['params', '--write', str(tmp_path / 'missing')]) == 2
