"""Open whatever a user points a command at as herd runs on one clock.

* a trajectory CSV (``time,agent,x,y[,run]``) is read as is;
* GPS data — a GPS CSV (``time,agent,lat,lon[,alt]``), a Movebank CSV, a GPX file or a
  rosbag2 (directory, ``.mcap`` or ``.db3``) — goes through the ingest path
  (:mod:`herd_ros.ingest.pipeline`: WGS84 → ENU → Kalman filter with gating → uniform clock).
"""
from __future__ import annotations

from pathlib import Path

from herd_ros.errors import HerdInputError
from herd_ros.trajectory import HerdTrajectory, read_trajectory_csv


def is_trajectory_csv(path: Path) -> bool:
    if path.suffix.lower() != '.csv' or not path.is_file():
        return False
    with open(path, newline='') as fh:
        header = [h.strip().lower() for h in fh.readline().split(',')]
    return {'x', 'y', 'time', 'agent'} <= set(header)


def load_runs(path, dt: float | None = None, smoother: str = 'none',
              **filter_params) -> tuple[list[HerdTrajectory], list | None]:
    """Runs and the datum (lat, lon, alt) they are relative to (None for a trajectory CSV)."""
    path = Path(path)
    if not path.exists():
        raise HerdInputError(f'{path}: no such file or directory')
    if is_trajectory_csv(path):
        return read_trajectory_csv(path), None
    from herd_ros.ingest import pipeline
    if dt is None:
        raise HerdInputError(f'{path}: GPS data needs --dt (the herd clock step, s)')
    fixes = pipeline.load_fixes(path)
    result = pipeline.trajectory_from_fixes(fixes, dt=dt, smoother=smoother, **filter_params)
    traj = result.trajectory if hasattr(result, 'trajectory') else result
    datum = getattr(result, 'datum', None)
    if datum is None:
        datum = traj.meta.get('datum')
    return [traj], (list(datum) if datum is not None else None)
