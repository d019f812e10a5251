"""Convert the real CC0 herds of the R package `contact` into the project's shipped data.

    .venv/bin/python -m pip install pyreadr          # only needed for this conversion
    .venv/bin/python bags/convert_contact.py DIR     # DIR holds baboons.rda, calves2018.rda

writes, next to this script:

* ``baboons_1h/``: a rosbag2 (mcap) with one sensor_msgs/NavSatFix topic per baboon
  (``/herd/baboon_<id>/fix``), header stamp = the fix's timestamp (UTC), status STATUS_FIX,
  covariance UNKNOWN, altitude NaN. Every fix is kept as published (no filtering, no
  interpolation).
* ``steers_72h.csv``: the steers as a trajectory CSV (``time,agent,x,y``; time in epoch
  seconds, x/y in the real-time location system's planar metres), every fix kept, sorted by
  time then agent. Irregular intervals: ``herd-ros fit``/``ingest`` filter it onto a clock.

Deterministic: running it again gives the same files.
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent


def agent_id(prefix: str, raw) -> str:
    """A valid ROS name token: ``<prefix>_<id>`` with anything but [A-Za-z0-9_] dropped."""
    return f'{prefix}_{re.sub(r"[^A-Za-z0-9_]", "", str(raw))}'


def epoch_seconds(values) -> np.ndarray:
    """UTC datetimes (naive = UTC) -> float epoch seconds, sub-second precision kept."""
    t = pd.to_datetime(values)
    if getattr(t.dt, 'tz', None) is not None:
        t = t.dt.tz_convert('UTC').dt.tz_localize(None)
    return (t - pd.Timestamp('1970-01-01')).dt.total_seconds().to_numpy()


def convert_baboons(src: Path, out_dir: Path) -> Path:
    import pyreadr

    from herd_ros.io.bags import write_fix_bag
    df = pyreadr.read_r(str(src))['baboons']
    fixes = pd.DataFrame({
        'time': np.round(epoch_seconds(df['dateTime']), 3),
        'agent': [agent_id('baboon', a) for a in df['individual.local.identifier']],
        'lat': df['location.lat'].to_numpy(float),
        'lon': df['location.long'].to_numpy(float),
        'alt': np.nan, 'status': 0, 'position_covariance_type': 0,
        'cov_ee': np.nan, 'cov_en': np.nan, 'cov_nn': np.nan})
    fixes = fixes.sort_values(['time', 'agent'], kind='stable').reset_index(drop=True)
    if out_dir.exists():
        raise SystemExit(f'{out_dir} exists: remove it first')
    return write_fix_bag(out_dir, fixes)


def convert_steers(src: Path, out_csv: Path) -> Path:
    import pyreadr
    df = pyreadr.read_r(str(src))['calves2018']
    table = pd.DataFrame({'time': np.round(epoch_seconds(df['dateTime']), 3),
                          'agent': [agent_id('steer', a) for a in df['calftag']],
                          'x': np.round(df['x'].to_numpy(float), 3),
                          'y': np.round(df['y'].to_numpy(float), 3)})
    table = table.sort_values(['time', 'agent'], kind='stable')
    table.to_csv(out_csv, index=False, float_format='%.3f')
    return out_csv


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print(__doc__)
        return 2
    src = Path(argv[0])
    print(convert_baboons(src / 'baboons.rda', HERE / 'baboons_1h'))
    print(convert_steers(src / 'calves2018.rda', HERE / 'steers_72h.csv'))
    return 0


if __name__ == '__main__':
    sys.exit(main())
