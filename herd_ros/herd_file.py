"""The herd file: one YAML that says everything herd-specific about a live graph, and the
node parameters it implies.

``herd-ros demo`` and ``launch/herd.launch.py`` both read a herd file and build every node's
parameters with :func:`node_parameters`, so the two cannot drift. ``herd-ros herd-file BAG``
writes one from a recording with the demo's data-derived choices
(:func:`herd_ros.herd_setup.herd_setup_from_fixes`); edit it by hand to fix a datum, draw a
fence or rename robots. Format (all lengths in metres of the ENU frame about ``datum``)::

    herd_file: 1
    bag: ../bags/baboons_1h      # default recording to replay; relative to this file
    rate: 30.0                   # replay speed-up
    herd:
      agents: [b01, b02, ...]    # collar ids (/herd/<id>/fix), the order of /herd/poses
      datum: [lat, lon, alt]     # ENU origin; [] = the first valid fix
      dt: 5.0                    # herd clock step (s)
      stale_after: 30.0          # s of data time without a fix before a collar is NaN
      reinit_after_gap: 300.0    # s of silence that restarts a collar's track
      law: shared                # pairwise or shared
      interaction_radius: 60.0   # shared law
      field_grid: [3, 2]         # environment field centres nx, ny over field_bounds
      field_bounds: [xmin, xmax, ymin, ymax]
    fence: [[x, y], ...]         # polygon the robots stay in; [] = none
    robots:
      names: [robot_1, ...]      # one per animal, same order (robot k imitates agent k)
      start: [[x, y], ...]       # initial positions
      max_speed: 1.2             # m/s

Nothing here imports rclpy: the launch file and the command line share it.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import yaml

from herd_ros.errors import HerdInputError
from herd_ros.herd_setup import HerdSetup, divides

FORMAT_VERSION = 1


class _NoAliasDumper(yaml.SafeDumper):
    """ROS's parameter-file parser refuses YAML anchors and aliases."""

    def ignore_aliases(self, data):
        return True


def dump_yaml(data) -> str:
    """``data`` as YAML in the layout the model and herd files use (block mappings, inline
    lists)."""
    return yaml.dump(data, Dumper=_NoAliasDumper, sort_keys=False, default_flow_style=None)


def herd_file_dict(setup: HerdSetup, bag=None, relative_to=None) -> dict:
    """The herd file of ``setup`` (``bag`` written relative to ``relative_to`` if given)."""
    bag_text = ''
    if bag is not None:
        bag_text = str(bag)
        if relative_to is not None:
            try:
                bag_text = os.path.relpath(Path(bag).resolve(), Path(relative_to).resolve())
            except ValueError:                       # another drive (Windows)
                bag_text = str(Path(bag).resolve())
    r = lambda v, n=3: round(float(v), n)            # noqa: E731 - readable metres
    return {
        'herd_file': FORMAT_VERSION,
        'bag': bag_text,
        'rate': float(setup.rate),
        'herd': {
            'agents': list(setup.agents),
            'datum': [round(float(v), 9) for v in setup.datum],
            'dt': float(setup.dt),
            'stale_after': float(setup.stale_after),
            'reinit_after_gap': float(setup.reinit_after_gap),
            'law': setup.law,
            'interaction_radius': r(setup.interaction_radius),
            'field_grid': [int(g) for g in setup.field_grid],
            'field_bounds': [r(b) for b in setup.field_bounds],
            **({'clock_dt': float(setup.clock)} if setup.clock != setup.dt else {}),
        },
        'fence': [[r(x), r(y)] for x, y in setup.fence],
        'robots': {
            'names': list(setup.robots),
            'start': [[r(x), r(y)] for x, y in setup.robot_start],
            'max_speed': r(setup.robot_max_speed),
        },
    }


def write_herd_file(path, setup: HerdSetup, bag=None, header: str = '') -> Path:
    """Write ``setup`` (and the ``bag`` it came from) as a herd file at ``path``, ``header`` as
    comments on top; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    body = dump_yaml(herd_file_dict(setup, bag, relative_to=path.parent))
    lines = [f'# {line}' if line else '#' for line in header.splitlines()]
    path.write_text(('\n'.join(lines) + '\n' if lines else '') + body)
    return path


def _need(mapping, key, where):
    if not isinstance(mapping, dict) or key not in mapping:
        raise HerdInputError(f'{where}: missing key {key!r}')
    return mapping[key]


def _numbers(value, where, count=None):
    try:
        out = [float(v) for v in value]
    except (TypeError, ValueError):
        raise HerdInputError(f'{where}: expected a list of numbers, got {value!r}') from None
    if count is not None and len(out) != count:
        raise HerdInputError(f'{where}: expected {count} numbers, got {len(out)}')
    if not all(math.isfinite(v) for v in out):
        raise HerdInputError(f'{where}: numbers must be finite, got {value!r}')
    return out


def read_herd_file(path) -> tuple[HerdSetup, Path | None]:
    """(setup, bag) of a herd file; the bag is resolved against the file's folder (None if
    the file names none). Every problem is one :class:`HerdInputError` naming the key."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding='utf-8'))
    except FileNotFoundError:
        raise HerdInputError(f'{path}: no such herd file') from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise HerdInputError(f'{path}: not a readable YAML herd file ({exc.__class__.__name__})'
                             ) from None
    w = str(path)
    if not isinstance(data, dict) or data.get('herd_file') != FORMAT_VERSION:
        raise HerdInputError(f'{w}: not a herd file (expected "herd_file: {FORMAT_VERSION}" '
                             f'at the top; write one with herd-ros herd-file BAG)')
    herd = _need(data, 'herd', w)
    robots = _need(data, 'robots', w)
    agents = [str(a) for a in _need(herd, 'agents', w)]
    from herd_ros.model.model_file import check_agent_id
    for a in agents:
        check_agent_id(a)
    if not agents or len(set(agents)) != len(agents):
        raise HerdInputError(f'{w}: herd.agents must be distinct collar ids, got {agents}')
    datum = _numbers(herd.get('datum', []), f'{w}: herd.datum')
    if datum and len(datum) not in (2, 3):
        raise HerdInputError(f'{w}: herd.datum must be [], [lat, lon] or [lat, lon, alt]')
    datum = datum + [0.0] * (3 - len(datum)) if datum else []
    dt = float(_need(herd, 'dt', w))
    law = str(herd.get('law', 'pairwise'))
    if law not in ('pairwise', 'shared'):
        raise HerdInputError(f'{w}: herd.law must be pairwise or shared, got {law!r}')
    grid = [int(v) for v in _numbers(_need(herd, 'field_grid', w), f'{w}: herd.field_grid', 2)]
    bounds = _numbers(_need(herd, 'field_bounds', w), f'{w}: herd.field_bounds', 4)
    if not (bounds[0] < bounds[1] and bounds[2] < bounds[3]) or min(grid) < 1:
        raise HerdInputError(f'{w}: herd.field_bounds must be [xmin, xmax, ymin, ymax] with '
                             f'min < max and field_grid >= [1, 1]')
    fence = data.get('fence') or []
    fence = [_numbers(p, f'{w}: fence vertex', 2) for p in fence]
    if fence and len(fence) < 3:
        raise HerdInputError(f'{w}: fence needs at least 3 vertices (or [] for none)')
    names = [str(r) for r in _need(robots, 'names', w)]
    for r in names:
        check_agent_id(r)
    start = [_numbers(p, f'{w}: robots.start', 2) for p in _need(robots, 'start', w)]
    if len(start) != len(names) or len(names) != len(agents):
        raise HerdInputError(f'{w}: robots.names and robots.start need one entry per agent '
                             f'({len(agents)}), got {len(names)} and {len(start)}')
    positive = {'herd.dt': dt, 'herd.stale_after': herd.get('stale_after', 30.0),
                'herd.reinit_after_gap': herd.get('reinit_after_gap', 300.0),
                'herd.interaction_radius': herd.get('interaction_radius', 60.0),
                'robots.max_speed': _need(robots, 'max_speed', w),
                'rate': data.get('rate', 1.0)}
    for key, value in positive.items():
        try:
            ok = float(value) > 0 and math.isfinite(float(value))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise HerdInputError(f'{w}: {key} must be a positive number, got {value!r}')
    clock_dt = float(herd.get('clock_dt', dt))
    if not (math.isfinite(clock_dt) and divides(clock_dt, dt)):
        raise HerdInputError(f'{w}: herd.clock_dt must divide herd.dt ({dt:g} s), got '
                             f'{herd.get("clock_dt")!r}')
    bag = data.get('bag') or None
    if bag is not None:
        bag = Path(bag)
        if not bag.is_absolute():
            bag = (path.parent / bag).resolve()
    setup = HerdSetup(
        agents=agents, datum=datum, dt=dt, stale_after=float(positive['herd.stale_after']),
        reinit_after_gap=float(positive['herd.reinit_after_gap']), field_grid=grid,
        field_bounds=bounds, fence=fence, robots=names, robot_start=start,
        robot_max_speed=float(positive['robots.max_speed']), law=law,
        interaction_radius=float(positive['herd.interaction_radius']), duration_s=float('nan'),
        rate=float(positive['rate']), notes={'herd_file': str(path)},
        clock_dt=clock_dt if clock_dt != dt else 0.0)
    return setup, bag


#: the robots follow the live law once it has this many model steps per parameter (an
#: animal's least squares with fewer overfits: on a 72-hour duty-cycled cattle analog, at
#: one to two steps per parameter the robots ran 10 to 57 times their animals' speed)
MIN_STEPS_PER_PARAMETER = 3


def live_law_size(setup) -> int:
    """Parameters per animal of the estimator's live law for ``setup``: the
    :attr:`~herd_ros.model.model_structure.ModelStructure.n_params` of its structure, with
    the estimator's default distance profile and no alignment (1 + 2(N − 1) + 2K pairwise,
    1 + B + 2K shared)."""
    from herd_ros.model.model_structure import ModelStructure
    from herd_ros.params.estimator import PARAMS
    return ModelStructure(tuple(setup.agents), float(setup.dt), setup.law,
                          tuple(int(g) for g in setup.field_grid),
                          tuple(float(b) for b in setup.field_bounds),
                          float(setup.interaction_radius),
                          int(PARAMS['profile_size'].default)).n_params


def node_parameters(setup: HerdSetup, bag, out_dir=None, rate=None,
                    composed: bool = False) -> dict:
    """Every node's parameters for ``setup``: {node name: {'ros__parameters': {...}}}.

    What `herd-ros demo` and `launch/herd.launch.py` both pass (on top of config/*.yaml).
    ``out_dir``: where the estimator writes its model and checkpoint (None = the nodes' data
    directory, ``$ROS_HOME/herd_ros``). ``composed``: the one-process demo, which stops the
    graph itself when the bag ends (replay does not exit) and keeps /clock at 40 Hz (every
    clock message is a callback in every node of that one Python process).
    """
    common = {'use_sim_time': True}
    init = []
    for x, y in setup.robot_start:
        init += [float(x), float(y), 0.0]
    dt = float(setup.dt)
    herd = {'agents': list(setup.agents), 'dt': dt}
    field = {'field_grid': [int(g) for g in setup.field_grid],
             'field_bounds': [float(b) for b in setup.field_bounds]}
    fence = [float(v) for v in np.asarray(setup.fence, dtype=float).ravel()]
    fence_param = {'fence': fence} if fence else {}
    v_max = float(setup.robot_max_speed)
    out = Path(out_dir) if out_dir is not None else None
    files = ({'model_out': str(out / 'learned_model.yaml'),
              'checkpoint_path': str(out / 'estimator_checkpoint.npz')} if out is not None
             else {'model_out': 'herd_model.yaml', 'checkpoint_path': 'estimator_checkpoint.npz'})
    replay = {'bag': str(bag), 'rate': float(rate if rate is not None else setup.rate),
              'loop': False, 'publish_clock': True,
              # the replay waits until every node that takes a fix topic has subscribed:
              # nothing of the bag is lost to a node still starting
              'wait_for_subscribers': 1,
              'clock_rate_hz': 40.0 if composed else 100.0,
              'exit_when_done': not composed}
    # /herd/poses on the clock (each fix in it within a step); the estimator learns at dt
    gps = {**common, **herd, 'dt': setup.clock, 'stale_after': float(setup.stale_after),
           'reinit_after_gap': float(setup.reinit_after_gap), 'fix_queue_depth': 1000}
    if setup.datum:
        gps['datum'] = [float(v) for v in setup.datum]
    return {
        'replay': {'ros__parameters': replay},
        'gps_ingest': {'ros__parameters': gps},
        'estimator': {'ros__parameters': {
            **common, **herd, **field, 'law': setup.law, 'forgetting': 1.0,
            'interaction_radius': float(setup.interaction_radius), **files,
            'checkpoint_period_s': 3600.0}},
        'controller': {'ros__parameters': {
            # the model's structure (agents, dt, law, field) comes from the estimator's
            # /herd/model/structure: declared once, there
            **common, 'robots': list(setup.robots), 'assignment': list(setup.agents),
            'mode': 'herd_model',
            # the estimator's first five minutes of data (at least 30 steps) are too few
            # for a usable law, and so are fewer than three steps per parameter of it
            'model_source': 'topic',
            'model_min_updates': int(max(30, np.ceil(300.0 / dt),
                                         MIN_STEPS_PER_PARAMETER * live_law_size(setup))),
            'noise': True, 'seed': 0,
            # four ticks per model step: the law is held over each herd-clock interval and
            # stepped at its ticks (HerdClockHold), so the robots run the discrete law exactly
            'rate_hz': 4.0 / dt, 'safety_horizon_s': dt,
            'max_speed': v_max, 'kinematics': 'holonomic', 'odom_timeout_s': 3.0 * dt,
            **fence_param}},
        'fleet_sim': {'ros__parameters': {
            **common, 'robots': list(setup.robots), 'kinematics': 'holonomic',
            # a step per half model step of data time (not per /clock message)
            'rate_hz': float(min(2.0, 2.0 / setup.clock)), 'initial_poses': init,
            'max_speed': v_max,
            'max_accel': float(max(0.5, v_max)), 'cmd_timeout_s': 1.5 * dt,
            **fence_param, 'datum': [float(v) for v in (setup.datum or [0.0, 0.0, 0.0])]}},
    }
