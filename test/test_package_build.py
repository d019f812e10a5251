"""The package builds with colcon (from PyPI, in this venv) and installs like a ROS package."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO, VENV_BIN

EXECUTABLES = ['gps_ingest', 'estimator', 'controller', 'fleet_sim', 'replay', 'record',
               'herd-ros']


@pytest.fixture(scope='module')
def colcon_install(tmp_path_factory):
    colcon = VENV_BIN / 'colcon'
    if not colcon.exists():
        pytest.fail('colcon is not installed in the venv: run `make setup`')
    work = tmp_path_factory.mktemp('colcon')
    src = work / 'src' / 'herd_ros'
    # a clean source tree: the tracked files and the working copies of everything else
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(
        '.venv', '.git', 'build', 'install', 'log', 'demo_out', '__pycache__', '*.egg-info',
        '.pytest_cache'))
    env = dict(os.environ)
    env['AMENT_PREFIX_PATH'] = sys.prefix
    proc = subprocess.run(
        [str(colcon), '--log-base', str(work / 'log'), 'build', '--base-paths', str(work / 'src'),
         '--build-base', str(work / 'build'), '--install-base', str(work / 'install')],
        cwd=work, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return work / 'install'


def test_every_executable_lands_in_lib(colcon_install):
    lib = colcon_install / 'herd_ros' / 'lib' / 'herd_ros'
    for name in EXECUTABLES:
        assert (lib / name).is_file(), f'{name} missing from {lib}'
        assert os.access(lib / name, os.X_OK)


def test_share_directory_found_by_ament_index(colcon_install):
    env = dict(os.environ)
    env['AMENT_PREFIX_PATH'] = f'{colcon_install / "herd_ros"}:{sys.prefix}'
    code = ('from ament_index_python.packages import get_package_share_directory as g; '
            'import os; d = g("herd_ros"); print(d); '
            'print(sorted(os.listdir(os.path.join(d, "config"))))')
    out = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True,
                         timeout=60, cwd=colcon_install)
    assert out.returncode == 0, out.stderr
    share, configs = out.stdout.splitlines()[:2]
    assert Path(share) == colcon_install / 'herd_ros' / 'share' / 'herd_ros'
    assert (Path(share) / 'package.xml').is_file()
    assert '.yaml' in configs, configs


def test_colcon_installed_controller_runs_with_a_model_file(colcon_install, tmp_path, ros_env):
    """`install/herd_ros/lib/herd_ros/controller --ros-args --params-file <model file>` starts,
    drives its robots' topics and stops cleanly (the colcon install, not the venv's copy)."""
    import signal
    import time

    from herd_ros.model.model_file import save_model
    from herd_ros.synthesis.known_truth import make_truth_model

    model_file = save_model(make_truth_model(3, seed=1), tmp_path / 'model.yaml')
    env = dict(ros_env)
    site = next((colcon_install / 'herd_ros' / 'lib').glob('python3*/site-packages'))
    env['PYTHONPATH'] = f'{site}:{env.get("PYTHONPATH", "")}'
    env['AMENT_PREFIX_PATH'] = f'{colcon_install / "herd_ros"}:{sys.prefix}'
    exe = colcon_install / 'herd_ros' / 'lib' / 'herd_ros' / 'controller'
    proc = subprocess.Popen([str(exe), '--ros-args', '--params-file', str(model_file),
                             '-p', 'robots:=[robot_1, robot_2, robot_3]'], cwd=tmp_path,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        time.sleep(4.0)
        assert proc.poll() is None, proc.communicate()[0]
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, out
    assert 'herd_model' in out and 'Traceback' not in out, out
    assert str(site) in subprocess.run(
        [sys.executable, '-c', 'import herd_ros, os; print(os.path.dirname(herd_ros.__file__))'],
        env=env, capture_output=True, text=True, timeout=60, cwd=tmp_path).stdout


def test_install_setup_bash_puts_the_package_on_the_ament_path(colcon_install):
    """What a ROS user does after `colcon build`: `source install/setup.bash` (colcon-bash)."""
    setup = colcon_install / 'setup.bash'
    assert setup.is_file(), 'no install/setup.bash: colcon-bash missing from the build tools'
    proc = subprocess.run(['bash', '-c', f'source {setup} && echo "$AMENT_PREFIX_PATH"'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert str(colcon_install / 'herd_ros') in proc.stdout.strip().split(':'), proc.stdout
    assert (colcon_install / 'herd_ros' / 'lib' / 'herd_ros' / 'herd-ros').exists()
