"""The launch files (run by `ros2 launch` on a full ROS install; `launch` is not on PyPI).

Checked statically: each compiles, every executable it starts is a console script of the
package, and every config file it loads is shipped.
"""
import ast
import re

import pytest
from conftest import REPO

#: each launch file and the nodes it starts (record is started by hand when wanted)
LAUNCHES = {'herd.launch.py': {'gps_ingest', 'estimator', 'controller', 'fleet_sim', 'replay'},
            'herding.launch.py': {'herd_sim', 'fleet_sim', 'controller'}}


def test_every_launch_file_is_checked():
    assert {p.name for p in (REPO / 'launch').glob('*.launch.py')} == set(LAUNCHES)


@pytest.mark.parametrize('name', sorted(LAUNCHES))
def test_launch_file_names_real_executables_and_configs(name):
    launch = REPO / 'launch' / name
    source = launch.read_text()
    compile(source, str(launch), 'exec')
    tree = ast.parse(source)
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)
               and isinstance(n.value, str)}
    setup = (REPO / 'setup.py').read_text()
    nodes = set(re.search(r"NODES = \[(.*?)\]", setup).group(1).replace("'", '').replace(
        ' ', '').split(','))
    started = {s for s in strings if s in nodes}
    assert started == LAUNCHES[name], f'{name} starts {sorted(started)}'
    for node in nodes:
        assert (REPO / 'config' / f'{node}.yaml').is_file(), f'config/{node}.yaml missing'
    for config in {s for s in strings if re.fullmatch(r'[a-z_]+\.yaml', s)}:
        assert (REPO / 'config' / config).is_file(), f'config/{config} missing'
    assert 'generate_launch_description' in {n.name for n in ast.walk(tree)
                                             if isinstance(n, ast.FunctionDef)}
