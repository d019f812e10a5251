"""Open whatever a user points a command at as herd runs on one clock.

* a trajectory CSV (``time,agent,x,y[,run]``) on a uniform clock is read as is (agents
  missing at some steps are NaN there);
* a trajectory CSV of irregular planar fixes (real-time location systems, UWB: metres, any
  intervals) goes through the ingest path without the geodesy;
* GPS data — a GPS CSV (``time,agent,lat,lon[,alt]``), a Movebank CSV, a GPX file or a
  rosbag2 (directory, ``.mcap`` or ``.db3``) — goes through the ingest path
  (:mod:`herd_ros.ingest.pipeline`: WGS84 → ENU → Kalman filter with gating → uniform clock).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from herd_ros.errors import HerdInputError
from herd_ros.trajectory import HerdTrajectory, clock_is_uniform, read_trajectory_csv


def is_trajectory_csv(path: Path) -> bool:
    """Whether ``path`` is a trajectory CSV (header ``time,agent,x,y``), not GPS data."""
    if path.suffix.lower() != '.csv' or not path.is_file():
        return False
    with open(path, 'rb') as fh:
        first = fh.readline(65536)
    try:
        line = first.decode('utf-8-sig')
    except UnicodeDecodeError:
        return False                    # the format readers say what is wrong with it
    header = [h.strip().lower() for h in line.split(',')]
    return {'x', 'y', 'time', 'agent'} <= set(header)


def planar_fixes_from_runs(path, raw=None) -> pd.DataFrame:
    """The planar fixes table (:func:`~herd_ros.ingest.pipeline.planar_fixes`) of a
    trajectory CSV of irregular planar fixes (RTLS, UWB: metres, any intervals)."""
    from herd_ros.ingest import pipeline
    raw = read_trajectory_csv(path, require_uniform=False) if raw is None else raw
    if len(raw) > 1:
        raise HerdInputError(f'{path}: irregular planar fixes with a run column; ingest '
                             f'each run separately')
    r = raw[0]
    have = np.isfinite(r.positions[..., 0])
    tt, ii = np.nonzero(have)
    table = pd.DataFrame({'time': r.times[tt], 'agent': np.asarray(r.agents)[ii],
                          'x': r.positions[tt, ii, 0], 'y': r.positions[tt, ii, 1]})
    return pipeline.planar_fixes(table)


def load_runs(path, dt: float | None = None, smoother: str = 'none',
              **filter_params) -> tuple[list[HerdTrajectory], list | None]:
    """Runs and the datum (lat, lon, alt) they are relative to (None for planar data).
    ``dt`` None: the herd clock step comes from the fix intervals. Fixes are tracked with
    one motion model for every collar unless ``motion_model`` says otherwise: the herd law
    is learned at the clock's step, and on the shipped real herds it predicts the fixed
    model's track better than the per-collar fitted one, which follows the fixes' small
    jitter (doc/gps_ingest.md, "Tracking")."""
    filter_params.setdefault('motion_model', 'fixed')
    if filter_params['motion_model'] == 'auto':
        filter_params['motion_model'] = 'fixed'

    path = Path(path)
    if not path.exists():
        raise HerdInputError(f'{path}: no such file or directory')
    from herd_ros.ingest import pipeline
    if is_trajectory_csv(path):
        raw = read_trajectory_csv(path, require_uniform=False)
        # on one clock: uniform steps, and most agents at most ticks (a stale collar leaves
        # holes; irregular fixes of an RTLS, merged, look like a 1 s clock with 90 % holes)
        if dt is None and all(clock_is_uniform(r.times)
                              and np.isfinite(r.positions[..., 0]).mean() >= 0.5
                              for r in raw):
            return read_trajectory_csv(path), None
        traj = pipeline.trajectory_from_fixes(planar_fixes_from_runs(path, raw), dt=dt,
                                              smoother=smoother, **filter_params)
        return [traj], None
    fixes = pipeline.load_fixes(path)
    result = pipeline.trajectory_from_fixes(fixes, dt=dt, smoother=smoother, **filter_params)
    traj = result.trajectory if hasattr(result, 'trajectory') else result
    datum = getattr(result, 'datum', None)
    if datum is None:
        datum = traj.meta.get('datum')
    return [traj], (list(datum) if datum is not None else None)
