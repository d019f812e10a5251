"""Shared fixtures. DDS stays on this machine: loopback-only discovery, per-run domain id.

Set at import time, before any test module can import rclpy, so in-process nodes inherit
it; subprocess tests take ``ros_env`` (a fresh domain id each test, so leftovers of one
test never talk to the next).
"""
import atexit
import itertools
import os
import random
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ['ROS_STATIC_PEERS'] = ''
os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 100)))
# pytest-xdist (make test runs two workers): each worker its own band of domain ids, so the
# in-process nodes and subprocess graphs of one worker never meet another's
_WORKER = int(os.environ.get('PYTEST_XDIST_WORKER', 'gw0')[2:] or 0)
_WORKERS = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1'))
_BAND = 100 // max(_WORKERS, 1)
if _WORKERS > 1:
    os.environ['ROS_DOMAIN_ID'] = str(1 + _WORKER * _BAND
                                      + (int(os.environ['ROS_DOMAIN_ID']) % _BAND))
os.environ.setdefault('MPLBACKEND', 'Agg')
# The collar kernels use every core by default (herd_ros.ingest.collar_threads). Under
# xdist the workers already fill the cores, and a worker's ingest on all of them takes CPU
# from the other worker's real-time graphs. One thread per worker process unless the run
# says otherwise; test_collar_threads sets its own counts.
if _WORKERS > 1:
    os.environ.setdefault('HERD_ROS_THREADS', '1')
# Nodes write their files (estimator checkpoint and model) under $ROS_HOME/herd_ros: the
# tests' go to a directory of their own, never the user's ~/.ros
# (removed when this process ends: each xdist worker and the controller make their own)
os.environ['ROS_HOME'] = tempfile.mkdtemp(prefix='herd_ros_test_ros_home_')
atexit.register(shutil.rmtree, os.environ['ROS_HOME'], ignore_errors=True)

REPO = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent
_prefix = str(Path(sys.prefix))
if _prefix not in os.environ.get('AMENT_PREFIX_PATH', '').split(':'):
    os.environ['AMENT_PREFIX_PATH'] = ':'.join(
        p for p in [_prefix, os.environ.get('AMENT_PREFIX_PATH', '')] if p)

# Domain ids for subprocess graphs: distinct from the run's own id, cycling in the
# worker's band of 1..100.
_base = int(os.environ['ROS_DOMAIN_ID']) - 1 - _WORKER * _BAND
_domains = (1 + _WORKER * _BAND + (_base + k) % _BAND for k in itertools.count(1))


def fresh_domain() -> str:
    """A domain id of this worker's band not used by any earlier test of the run."""
    return str(next(_domains))


@pytest.fixture
def ros_env():
    """Environment for subprocesses that start rclpy: loopback only, a domain of their own."""
    env = dict(os.environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['ROS_STATIC_PEERS'] = ''
    env['ROS_DOMAIN_ID'] = fresh_domain()
    env['PYTHONUNBUFFERED'] = '1'
    return env


@pytest.fixture
def console_script():
    """Path of an installed console script of this venv (`make test` installs the package)."""
    def find(name):
        path = VENV_BIN / name
        if not path.exists():
            pytest.fail(f'{name} is not installed in {VENV_BIN}: run `make setup`')
        return str(path)
    return find


def _extension_module(path):
    """The extension module at ``path``, loaded under its own name."""
    import importlib.util

    from herd_ros.ingest import aot
    spec = importlib.util.spec_from_file_location(aot.EXTENSION, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope='session')
def aot_kernels(tmp_path_factory):
    """The collar kernels compiled ahead of time from this tree
    (:class:`herd_ros.ingest.aot.AheadOfTime`): the extension ``make`` installed in the venv
    when it was built from these very sources (its digest of them equals the tree's), else
    compiled here into a temporary directory, as ``setup.py`` does (30 s). Skipped only where
    there is no C compiler, where ``setup.py`` cannot build the extension either."""
    import shutil
    import sysconfig

    from herd_ros.ingest import aot
    installed = sorted((Path(sysconfig.get_paths()['platlib']) / 'herd_ros' / 'ingest')
                       .glob(aot.EXTENSION + '.*'))
    for path in installed:
        module = _extension_module(path)
        if module.source_digest() == aot.source_digest():
            return aot.AheadOfTime(module)
    compiler = (sysconfig.get_config_var('CC') or 'cc').split()[0]
    if shutil.which(compiler) is None:
        pytest.skip(f'no C compiler ({compiler}): the kernels run through numba only')
    out = tmp_path_factory.mktemp('aot')
    aot.compiler(out).compile()
    return aot.AheadOfTime(_extension_module(next(out.glob(aot.EXTENSION + '.*'))))


@pytest.fixture(params=['jit', 'aot'])
def kernels(request, monkeypatch):
    """The test runs once with each compilation of the collar kernels: numba's JIT and the
    ahead-of-time extension (:mod:`herd_ros.ingest.aot`)."""
    from herd_ros.ingest import aot, collar_bank
    chosen = (aot.load_kernels('jit') if request.param == 'jit'
              else request.getfixturevalue('aot_kernels'))
    monkeypatch.setattr(collar_bank, 'KERNELS', chosen)     # the herd clock's too
    return chosen


#: fixtures that start ROS nodes or installed console scripts
_ROS_FIXTURES = {'ros_env', 'console_script', 'ros'}


def pytest_collection_modifyitems(config, items):
    """Markers that say what a test needs, so ``make test-fast`` can leave those out:
    ``ros`` for a test that starts rclpy nodes (in process: its module imports rclpy or the
    ROS harness; or as processes: it takes ``ros_env``/``console_script``), ``build`` for
    the colcon/setuptools package builds. ``make test`` runs everything."""
    modules = {}
    for item in items:
        path = Path(str(item.fspath))
        if path not in modules:
            text = path.read_text(encoding='utf-8') if path.exists() else ''
            modules[path] = ('import rclpy' in text or 'ros_harness' in text
                             or 'from rclpy' in text)
        if path.name == 'test_package_build.py':
            item.add_marker(pytest.mark.build)
        if modules[path] or _ROS_FIXTURES & set(getattr(item, 'fixturenames', ())):
            item.add_marker(pytest.mark.ros)
