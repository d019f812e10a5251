"""Offline ingest speed (issue 12, acceptance 1), in one run on the same fixes.

1. **Whole processes** on 360 000 fixes (200 collars × 30 min at 1 Hz, 3 m noise, 1 % jumps
   of 50 m, a GPS CSV): ``herd-ros ingest FIXES -o OUT --dt 1`` (the installed console
   script, with the kernels it finds: compiled at install, or numba's) against the plain
   filterpy loop of ``plain_filterpy_loop.py``, each timed from process start to exit,
   median of 3 (after one ingest run; that first run is reported too). The two are run in
   turns (ingest, loop, ingest, loop, ...) and the speed-up is the median of the three
   pairs' ratios: the machine's speed drifts over minutes, and run one after the other the
   two sides saw different machines (one run 11.8 x, the next 8.7 x). The collars are
   split over the machine's cores (``herd_ros.ingest.collar_threads``); the same ingest on
   one thread (``HERD_ROS_THREADS=1``) is timed too. Then the same ingest with
   ``HERD_ROS_KERNELS=jit`` (numba's cache filled by one run first).
2. **The core alone**: :class:`herd_ros.ingest.collar_bank.CollarBank` on 3.6 M fixes
   (1 000 collars × 1 h at 1 Hz): measurement covariances + the compiled filter loop,
   fixes per second, median of 3.
3. :func:`trajectory_from_fixes` in process, per smoother (fixes/s).

    .venv/bin/python test/bench/bench_ingest.py [--quick]
"""
import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

from herd_ros.ingest.geodesy import enu_to_geodetic  # noqa: E402

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


def herd_ros_command():
    script = Path(sys.executable).with_name('herd-ros')
    return [str(script)] if script.exists() else [sys.executable, '-m', 'herd_ros.cli.main']


def timed(cmd, **env):
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                   env={**os.environ, **env})
    return time.perf_counter() - t0


def thread_count():
    from herd_ros.ingest.collar_threads import thread_count
    return thread_count()


def installed_kernels():
    """Which collar kernels the installed package loads (``aot`` or ``jit``)."""
    code = 'from herd_ros.ingest.collar_bank import KERNELS; print(KERNELS.kind)'
    env = {k: v for k, v in os.environ.items() if k != 'PYTHONPATH'}
    return subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          cwd=tempfile.gettempdir(), env=env, check=True).stdout.strip()


def whole_processes(repeats):
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / 'fixes.csv'
        fixes = herd(200, 1800)
        fixes.to_csv(src, index=False, float_format='%.9f')
        ingest = herd_ros_command() + ['ingest', str(src), '-o', str(Path(tmp) / 'a.csv'),
                                       '--dt', '1']
        plain = [sys.executable, str(HERE / 'plain_filterpy_loop.py'), str(src),
                 str(Path(tmp) / 'b.csv')]
        fixed = ingest + ['--motion-model', 'fixed']
        first = timed(ingest)
        # ours and the loop in turns, so that both see the machine as it is then (its
        # speed drifts over minutes); the speed-up is the median of the pairs' ratios
        pairs = [(timed(ingest), timed(plain)) for _ in range(repeats)]
        ours, base = [a for a, _ in pairs], [b for _, b in pairs]
        paired = statistics.median(b / a for a, b in pairs)
        ours_fixed = [timed(fixed) for _ in range(repeats)]
        ours_one = [timed(ingest, HERD_ROS_THREADS='1') for _ in range(repeats)]
        timed(ingest, HERD_ROS_KERNELS='jit')
        jit = [timed(ingest, HERD_ROS_KERNELS='jit') for _ in range(repeats)]
    mo, mb, mj = statistics.median(ours), statistics.median(base), statistics.median(jit)
    mf = statistics.median(ours_fixed)
    m1 = statistics.median(ours_one)
    print(f'whole processes on {len(fixes)} fixes (200 collars x 30 min at 1 Hz), median of '
          f'{repeats}:')
    print(f'  herd-ros ingest           {mo:7.2f} s  ({len(fixes) / mo:9.0f} fixes/s; '
          f'kernels: {installed_kernels()}, {thread_count()} threads; first run: '
          f'{first:.2f} s)')
    print(f'  same, on one thread       {m1:7.2f} s  (HERD_ROS_THREADS=1: {mb / m1:.1f} x the '
          f'loop)')
    print(f'  same, --motion-model fixed {mf:6.2f} s  ({len(fixes) / mf:9.0f} fixes/s: one '
          f'model for all collars, as the loop)')
    print(f'  plain filterpy loop       {mb:7.2f} s  ({len(fixes) / mb:9.0f} fixes/s)')
    print(f'  speed-up                  {paired:7.1f} x (fitted models: the median of '
          f'{repeats} runs each\n'
          f'                                        followed by a loop run; '
          f'{mb / mo:.1f} x the ratio of the medians), {mb / mf:.1f} x (fixed model)')
    print(f'  herd-ros ingest, numba    {mj:7.2f} s  (HERD_ROS_KERNELS=jit: {mb / mj:.1f} x '
          f'the loop)')


def core(repeats, n=1000, seconds=3600):
    from herd_ros.ingest.collar_bank import KERNELS, CollarBank
    from herd_ros.ingest.collar_filter import FilterParams

    rng = np.random.default_rng(0)
    t = (1.7e9 + np.arange(seconds)[:, None] + rng.uniform(0, 0.2, (seconds, n))).reshape(-1)
    idx = np.tile(np.arange(n), seconds)
    p = (np.cumsum(rng.normal(0, 0.3, (seconds, n, 2)), axis=0).reshape(-1, 2)
         + rng.normal(0, 3, (seconds * n, 2)))
    jump = rng.random(len(t)) < 0.01
    p[jump] += 50
    status = np.zeros(len(t), np.int64)
    ctype = np.zeros(len(t), np.int64)
    cov = np.full((len(t), 9), np.nan)
    params = FilterParams(accel_std=0.05, velocity_tau=120.0, stale_after=30.0)
    CollarBank(n, params).process(idx[:10], t[:10], p[:10, 0], p[:10, 1], status[:10],
                                  np.tile(25 * np.eye(2), (10, 1, 1)))    # load the kernel
    times = []
    chunk = 500_000
    for _ in range(repeats):
        bank = CollarBank(n, params)
        t0 = time.perf_counter()
        for s in range(0, len(t), chunk):
            sl = slice(s, s + chunk)
            R = bank.measurement_covariances(ctype[sl], cov[sl])
            bank.process(idx[sl], t[sl], p[sl, 0], p[sl, 1], status[sl], R)
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    print(f'core alone (CollarBank: covariances + filter, kernels: {KERNELS.kind}), '
          f'{len(t)} fixes ({n} collars x {seconds / 3600:g} h at 1 Hz), median of {repeats}: '
          f'{med:.2f} s = {len(t) / med:,.0f} fixes/s')


def in_process(quick):
    from herd_ros.ingest.pipeline import trajectory_from_fixes

    cases = [(10, 3600, 'none', 5), (10, 3600, 'rts', 3), (10, 3600, 'fir', 5),
             (100, 3600, 'none', 3)]
    if quick:
        cases = cases[:1]
    print('trajectory_from_fixes in process (fixes -> ENU -> filters -> clock -> smoother):')
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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--quick', action='store_true', help='one repeat, fewer cases')
    args = ap.parse_args(argv)
    repeats = 1 if args.quick else 3
    os.environ.setdefault('PYTHONUNBUFFERED', '1')
    whole_processes(repeats)
    core(repeats)
    in_process(args.quick)
    print('reproduce with: .venv/bin/python test/bench/bench_ingest.py')


if __name__ == '__main__':
    main()
