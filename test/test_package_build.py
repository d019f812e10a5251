"""The package builds with colcon (from PyPI, in this venv) and installs like a ROS package."""
import os
import shutil
import signal
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


def test_colcon_build_compiles_the_collar_kernels(colcon_install, aot_kernels):
    """setup.py compiles the collar kernels ahead of time under colcon too (where a C
    compiler is present: ``aot_kernels`` skips otherwise), so `ros2 run herd_ros
    gps_ingest` starts without numba."""
    built = list(colcon_install.glob('herd_ros/lib/python3*/site-packages/herd_ros/ingest/'
                                     '_collar_kernels.*'))
    assert built, 'herd_ros/ingest/_collar_kernels was not built by colcon'


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


LAUNCH_DRIVER = """
import sys
from launch import LaunchService
from launch.actions import IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
# noninteractive: a SIGINT to launch is relayed to every node as one SIGINT (what a
# supervisor, an on_exit shutdown or launch_testing cause); an interactive launch assumes
# the terminal's Ctrl-C reached the whole process group and sends none
service = LaunchService(argv=sys.argv[2:], noninteractive=True)
service.include_launch_description(IncludeLaunchDescription(
    PythonLaunchDescriptionSource(sys.argv[1]), launch_arguments=[
        tuple(a.split(':=', 1)) for a in sys.argv[2:]]))
sys.exit(service.run())
"""


def _launch_env(colcon_install, ros_env):
    site = next((colcon_install / 'herd_ros' / 'lib').glob('python3*/site-packages'))
    env = dict(ros_env)
    env['PYTHONPATH'] = os.pathsep.join([str(site)] + [p for p in os.environ.get(
        'PYTHONPATH', '').split(os.pathsep) if p])
    env['AMENT_PREFIX_PATH'] = f'{colcon_install / "herd_ros"}:{sys.prefix}'
    return env


def _launch_env_or_skip(colcon_install, ros_env):
    """:func:`_launch_env`, or the test skipped where launch/launch_ros do not import."""
    env = _launch_env(colcon_install, ros_env)
    probe = subprocess.run([sys.executable, '-c', 'import launch, launch_ros.actions'],
                           env=env, capture_output=True, text=True)
    if probe.returncode != 0:
        reason = ('launch/launch_ros are not importable here (not on PyPI; a full ROS install '
                  'or a source install has them): ' + probe.stderr.strip().splitlines()[-1])
        print(reason)
        pytest.skip(reason)
    return env


@pytest.mark.slow
def test_launch_file_runs_the_graph_and_stops_without_escalation(colcon_install, tmp_path,
                                                                  ros_env):
    """Issue "a ROS user's first hour", acceptance 2: the colcon-installed launch file, run by
    launch's own LaunchService, brings data onto /herd/poses, /herd/model/params and
    /fleet/poses; one SIGINT to the launch process alone (launch, non-interactive, then asks
    each node with one SIGINT) ends everything without `escalating to 'SIGTERM'`."""
    env = _launch_env_or_skip(colcon_install, ros_env)
    from geometry_msgs.msg import PoseArray
    from std_msgs.msg import Float64MultiArray

    from ros_harness import TestListener
    launch_file = colcon_install / 'herd_ros' / 'share' / 'herd_ros' / 'launch' / 'herd.launch.py'
    log = open(tmp_path / 'launch.log', 'w')
    proc = subprocess.Popen([sys.executable, '-c', LAUNCH_DRIVER, str(launch_file),
                             'rate:=30.0'], env=env, stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    listener = TestListener(ros_env)
    try:
        seen = {t: listener.record(m, t) for t, m in (('/herd/poses', PoseArray),
                                                       ('/herd/model/params', Float64MultiArray),
                                                       ('/fleet/poses', PoseArray))}
        ok = listener.spin(90.0, until=lambda: all(len(v) >= 3 for v in seen.values()))
        assert ok, ({t: len(v) for t, v in seen.items()},
                    (tmp_path / 'launch.log').read_text()[-3000:])
        assert proc.poll() is None
        proc.send_signal(signal.SIGINT)              # the launch process only
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        listener.close()
        log.close()
    text = (tmp_path / 'launch.log').read_text()
    assert 'escalating' not in text, text[-3000:]
    assert 'Traceback' not in text, text[-3000:]
    assert text.count("sending signal 'SIGINT'") == 5, text[-3000:]
    herd = seen['/herd/poses'][-1][1]
    assert len(herd.poses) == 19                     # the shipped herd file: 19 baboons


@pytest.mark.slow
def test_herding_launch_file_brings_the_herd_into_the_goal(colcon_install, tmp_path, ros_env):
    """Issue 27, acceptance 3: ``ros2 launch herd_ros herding.launch.py`` (the colcon-installed
    file, run by launch's own LaunchService) ends with the herd inside the goal, checked from
    the poses on /herd/poses; one SIGINT ends the three nodes."""
    env = _launch_env_or_skip(colcon_install, ros_env)
    import numpy as np
    from geometry_msgs.msg import PoseArray

    from herd_ros.herding.benchmark import GOAL, GOAL_RADIUS
    from ros_harness import TestListener
    launch_file = (colcon_install / 'herd_ros' / 'share' / 'herd_ros' / 'launch'
                   / 'herding.launch.py')
    log = open(tmp_path / 'launch.log', 'w')
    proc = subprocess.Popen([sys.executable, '-c', LAUNCH_DRIVER, str(launch_file),
                             'rate:=40.0', 'seed:=1'], env=env, stdout=log,
                            stderr=subprocess.STDOUT, start_new_session=True)
    listener = TestListener(ros_env)

    def home(msgs):
        if not msgs:
            return False
        xy = np.array([(p.position.x, p.position.y) for p in msgs[-1][1].poses])
        return len(xy) == 14 and bool((np.hypot(*(xy - GOAL).T) <= GOAL_RADIUS).all())
    try:
        seen = listener.record(PoseArray, '/herd/poses')
        ok = listener.spin(120.0, until=lambda: home(seen))
        assert ok, (len(seen), (tmp_path / 'launch.log').read_text()[-3000:])
        first = np.array([(p.position.x, p.position.y) for p in seen[0][1].poses])
        assert (np.hypot(*(first - GOAL).T) > GOAL_RADIUS).all()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        listener.close()
        log.close()
    text = (tmp_path / 'launch.log').read_text()
    assert 'Traceback' not in text and 'escalating' not in text, text[-3000:]
