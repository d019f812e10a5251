"""Offline ingest throughput (fixes/s): GPS fixes -> ENU -> collar filters -> herd clock.

Synthetic herds at 1 Hz for one hour (3 m noise, 1 % jumps of 50 m), through
:func:`herd_ros.ingest.pipeline.trajectory_from_fixes`; medians over repeats.

    .venv/bin/python test/bench/bench_ingest.py
"""
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from herd_ros.ingest.geodesy import enu_to_geodetic  # noqa: E402
from herd_ros.ingest.pipeline import trajectory_from_fixes  # noqa: E402

DATUM = (27.0153, -108.7937, 100.0)


def herd(n_agents, seconds, seed=0):
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(n_agents):
        t = 1.7e9 + np.arange(seconds) + rng.uniform(0, 0.2, seconds)
        v = np.cumsum(rng.normal(0, 0.02, (seconds, 2)), axis=0).clip(-1, 1)
        p = np.cumsum(v, axis=0) + rng.uniform(-100, 100, 2)
        z = p + rng.normal(0, 3, p.shape)
        jump = rng.random(seconds) < 0.01
        z[jump] += 50
        lat, lon, _ = enu_to_geodetic(z[:, 0], z[:, 1], 0.0, *DATUM)
        frames.append(pd.DataFrame({'time': t, 'agent': f'cow_{i}', 'lat': lat, 'lon': lon,
                                    'alt': np.nan}))
    return pd.concat(frames).sort_values('time').reset_index(drop=True)


def main():
    cases = [(10, 3600, 'none', 5), (10, 3600, 'rts', 5), (10, 3600, 'fir', 5),
             (100, 3600, 'none', 3)]
    print(f'{"collars":>8} {"hours":>6} {"smoother":>9} {"fixes":>9} {"median s":>9} '
          f'{"fixes/s":>10}')
    for n, secs, smoother, repeats in cases:
        fixes = herd(n, secs)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            trajectory_from_fixes(fixes, 1.0, datum=DATUM, smoother=smoother)
            times.append(time.perf_counter() - t0)
        med = statistics.median(times)
        print(f'{n:>8} {secs / 3600:>6.1f} {smoother:>9} {len(fixes):>9} {med:>9.2f} '
              f'{len(fixes) / med:>10.0f}', flush=True)
    print('medians of 5 repeats (3 for 100 collars); reproduce with: '
          '.venv/bin/python test/bench/bench_ingest.py')


if __name__ == '__main__':
    main()
