"""The herd file (herd_ros/herd_file.py): written, read back, turned into node parameters;
bad files answered with one line; the launch file carries no herd of its own."""
import ast

import pytest
import yaml

from conftest import REPO
from herd_ros.cli.main import main
from herd_ros.errors import HerdInputError
from herd_ros.herd_file import node_parameters, read_herd_file, write_herd_file
from herd_ros.herd_setup import HerdSetup

SHIPPED = REPO / 'config' / 'herd_baboons.yaml'


def small_setup():
    return HerdSetup(
        agents=['cow_a', 'cow_b'], datum=[46.8, 7.1, 450.0], dt=20.0, stale_after=600.0,
        reinit_after_gap=900.0, field_grid=[2, 1], field_bounds=[-50.0, 50.0, -20.0, 20.0],
        fence=[[-60.0, -30.0], [60.0, -30.0], [60.0, 30.0], [-60.0, 30.0]],
        robots=['robot_1', 'robot_2'], robot_start=[[1.0, 2.0], [-3.0, 4.0]],
        robot_max_speed=1.5, law='pairwise', interaction_radius=40.0, duration_s=3600.0,
        rate=30.0)


def test_written_herd_file_reads_back_to_the_same_node_parameters(tmp_path):
    setup = small_setup()
    bag = tmp_path / 'bags' / 'my_bag'
    bag.mkdir(parents=True)
    path = write_herd_file(tmp_path / 'conf' / 'herd.yaml', setup, bag)
    assert yaml.safe_load(path.read_text())['bag'] == '../bags/my_bag'   # relative to file
    again, again_bag = read_herd_file(path)
    assert again_bag == bag.resolve()
    assert node_parameters(again, bag) == node_parameters(setup, bag)
    p = node_parameters(setup, bag)
    # what the herd fixes reaches every node that needs it
    assert p['gps_ingest']['ros__parameters']['agents'] == ['cow_a', 'cow_b']
    assert p['gps_ingest']['ros__parameters']['datum'] == [46.8, 7.1, 450.0]
    assert p['estimator']['ros__parameters']['dt'] == 20.0
    assert p['controller']['ros__parameters']['fence'] == \
        p['fleet_sim']['ros__parameters']['fence'] == [-60, -30, 60, -30, 60, 30, -60, 30]
    assert p['fleet_sim']['ros__parameters']['initial_poses'] == [1, 2, 0, -3, 4, 0]
    assert p['replay']['ros__parameters']['wait_for_subscribers'] == 1


@pytest.mark.parametrize('edit, message', [
    (lambda d: d.pop('herd_file'), 'not a herd file'),
    (lambda d: d['herd'].pop('dt'), "missing key 'dt'"),
    (lambda d: d['herd'].update(dt=-5), 'herd.dt must be a positive number'),
    (lambda d: d['herd'].update(field_bounds=[1, 0, 0, 1]), 'herd.field_bounds'),
    (lambda d: d['herd'].update(law='flock'), 'herd.law must be pairwise or shared'),
    (lambda d: d['robots'].update(start=[[0, 0]]), 'one entry per agent'),
    (lambda d: d.update(fence=[[0, 0], [1, 1]]), 'at least 3 vertices'),
    (lambda d: d['herd'].update(agents=['cow a', 'cow_b']), 'not a valid ROS name'),
    (lambda d: d['herd'].update(clock_dt=3.0), 'herd.clock_dt must divide herd.dt'),
])
def test_bad_herd_files_get_one_line(tmp_path, edit, message):
    data = yaml.safe_load(SHIPPED.read_text())
    edit(data)
    path = tmp_path / 'bad.yaml'
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(HerdInputError, match=message.replace('(', r'\(').replace('.', r'\.')):
        read_herd_file(path)


def test_shipped_herd_file_is_the_default_bags_herd():
    setup, bag = read_herd_file(SHIPPED)
    assert bag == (REPO / 'bags' / 'baboons_1h').resolve() and bag.exists()
    assert len(setup.agents) == len(setup.robots) == 19 and setup.law == 'shared'


def test_herd_file_command_writes_a_readable_file(tmp_path, capsys):
    out = tmp_path / 'cows.yaml'
    assert main(['herd-file', str(REPO / 'bags' / 'cows_3x1h'), '-o', str(out)]) == 0
    setup, bag = read_herd_file(out)
    assert setup.agents == ['cow_1', 'cow_2', 'cow_3'] and bag.name == 'cows_3x1h'
    assert 'wrote' in capsys.readouterr().out
    assert main(['herd-file', str(tmp_path / 'nothing'), '-o', str(out)]) == 2


def test_launch_file_has_no_herd_of_its_own():
    tree = ast.parse((REPO / 'launch' / 'herd.launch.py').read_text())
    numbers = [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)
               and isinstance(n.value, (int, float)) and not isinstance(n.value, bool)]
    assert numbers == [], f'numeric constants in the launch file: {numbers}'
    strings = [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)
               and isinstance(n.value, str)]
    herdish = [s for s in strings if s.startswith(('cow_', 'baboon_', 'robot_', 'steer'))]
    assert herdish == []
    assert 'herd_baboons.yaml' in ''.join(strings)     # the shipped default herd file


def test_the_herd_clock_is_the_largest_round_divisor_of_the_model_step_by_hand():
    from herd_ros.herd_setup import herd_clock_step
    assert herd_clock_step(120.0, 30.0, 5.0) == 30.0
    assert herd_clock_step(120.0, 45.0, 5.0) == 30.0      # 45 s is not a round step
    assert herd_clock_step(90.0, 30.0, 5.0) == 30.0
    assert herd_clock_step(5.0, 1.0, 5.0) == 5.0          # 1 Hz collars on the live 5 s clock
    assert herd_clock_step(7.0, 3.0, 5.0) == 7.0          # nothing between 5 and 3: dt


def test_duty_cycled_collars_get_a_finer_herd_clock_than_the_model_step(tmp_path):
    # collars fixing every 30-300 s: the law at the median interval (120 s), /herd/poses
    # every 30 s (a tick between nearly any two fixes), the estimator skipping the ticks in
    # between; the herd file carries the clock and the node parameters take it
    import numpy as np
    import pandas as pd

    from herd_ros.herd_setup import herd_setup_from_fixes
    from herd_ros.ingest.geodesy import enu_to_geodetic
    rng = np.random.default_rng(3)
    rows = []
    for i in range(3):
        t = 1.7e9 + np.cumsum(rng.uniform(30.0, 300.0, 400))
        e = 30.0 * i + np.cumsum(rng.normal(0, 3, 400))
        n = np.cumsum(rng.normal(0, 3, 400))
        lat, lon, _ = enu_to_geodetic(e, n, 0.0, 46.8, 7.1, 450.0)
        rows.append(pd.DataFrame({'time': t, 'agent': f'cow_{i}', 'lat': lat, 'lon': lon}))
    setup = herd_setup_from_fixes(pd.concat(rows), min_dt=5.0)
    assert setup.dt == 120.0 and setup.clock == 30.0
    assert 'every 30 s' in setup.describe()
    path = write_herd_file(tmp_path / 'herd.yaml', setup)
    again, _ = read_herd_file(path)
    assert again.clock == 30.0 and again.dt == 120.0
    p = node_parameters(again, tmp_path / 'bag')
    assert p['gps_ingest']['ros__parameters']['dt'] == 30.0
    assert p['estimator']['ros__parameters']['dt'] == 120.0
    assert p['fleet_sim']['ros__parameters']['rate_hz'] == pytest.approx(2.0 / 30.0)
    # a herd whose clock is its model step writes no clock (the shipped herd files)
    assert 'clock_dt' not in yaml.safe_load(write_herd_file(
        tmp_path / 'small.yaml', small_setup()).read_text())['herd']
