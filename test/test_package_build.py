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
