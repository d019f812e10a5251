"""The launch file (run by `ros2 launch` on a full ROS install; `launch` is not on PyPI).

Checked statically: it compiles, every executable it starts is a console script of the
package, and every config file it loads is shipped.
"""
import ast
import re

from conftest import REPO

LAUNCH = REPO / 'launch' / 'herd.launch.py'


def test_launch_file_names_real_executables_and_configs():
    source = LAUNCH.read_text()
    compile(source, str(LAUNCH), 'exec')
    tree = ast.parse(source)
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)
               and isinstance(n.value, str)}
    setup = (REPO / 'setup.py').read_text()
    nodes = set(re.search(r"NODES = \[(.*?)\]", setup).group(1).replace("'", '').replace(
        ' ', '').split(','))
    started = {s for s in strings if s in nodes}
    pipeline = nodes - {'record'}   # the graph; record is started by hand when wanted
    assert started == pipeline, f'launch starts {sorted(started)}, graph is {sorted(pipeline)}'
    for name in nodes:
        assert (REPO / 'config' / f'{name}.yaml').is_file(), f'config/{name}.yaml missing'
    assert 'generate_launch_description' in {n.name for n in ast.walk(tree)
                                             if isinstance(n, ast.FunctionDef)}
