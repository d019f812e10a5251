"""The baseline of bench_ingest.py: the plain filterpy loop a user would write.

One ``KalmanFilter`` per collar, constant velocity (``Q_discrete_white_noise``), predict and
update per fix, ENU by pymap3d, filtered positions per fix to a CSV. No gating, no outlier
handling, no herd clock: less work than ``herd-ros ingest`` does.

    python plain_filterpy_loop.py FIXES.csv OUT.csv
"""
import sys

import numpy as np
import pandas as pd
import pymap3d
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

fixes = pd.read_csv(sys.argv[1]).sort_values(['agent', 'time'], kind='stable')
lat0, lon0 = fixes['lat'].iloc[0], fixes['lon'].iloc[0]
fixes['e'], fixes['n'], _ = pymap3d.geodetic2enu(fixes['lat'].to_numpy(),
                                                 fixes['lon'].to_numpy(), 0.0, lat0, lon0, 0.0)
out = []
for agent, rows in fixes.groupby('agent'):
    kf = KalmanFilter(dim_x=4, dim_z=2)
    kf.H = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
    kf.R *= 25.0
    t_prev = None
    for t, e, n in zip(rows['time'], rows['e'], rows['n']):
        if t_prev is None:
            kf.x = np.array([[e], [n], [0.0], [0.0]])
            kf.P = np.diag([25.0, 25.0, 9.0, 9.0])
        else:
            dt = t - t_prev
            kf.F = np.array([[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1.0]])
            kf.Q = Q_discrete_white_noise(2, dt, 0.05 ** 2, block_size=2, order_by_dim=False)
            kf.predict()
            kf.update(np.array([e, n]))
        t_prev = t
        out.append((t, agent, kf.x[0, 0], kf.x[1, 0]))
pd.DataFrame(out, columns=['time', 'agent', 'x', 'y']).to_csv(sys.argv[2], index=False)
