"""Benchmark: batched RLS of the herd vs padasip's FilterRLS vs a per-agent numpy loop.

Agent-updates per second (one agent, one snapshot: its x and y rows) for herds of 3, 30 and
300 animals with the pairwise law (p = 1 + 2(N−1) + 2K) and 1 000 and 10 000 animals with
the shared law (p = 1 + B + 2K), K = 36 field centres (6x6 grid), B = 6. Ratios in one run.

- compiled: :class:`herd_ros.estimation.rls.HerdRLS` (directional forgetting, Joseph form),
  all agents in one call (herds with p > 400 in chunks of 50 agents to bound memory), by
  its numba kernel (:mod:`herd_ros.estimation.rls_kernels`); compile time excluded (the
  kernel is compiled or loaded from numba's cache when the estimator is built, and one
  warm-up update runs before timing).
- numpy: the same estimator with ``compiled=False``: the batched numpy path (the fallback
  when numba is not installed).
- padasip: ``padasip.filters.FilterRLS``, one filter per agent and component (x, y), each
  adapted once per snapshot (benchmark-only dependency: ``pip install padasip``).
- numpy loop: the textbook covariance-form RLS, one agent at a time.
The loop baselines are timed on a sample of agents (updates are independent per agent).

Also: the CPU share of one core for a 1 000-animal herd with the shared law at 1 Hz
(regressors with cKDTree + RLS update, process time per snapshot), compiled and numpy.
The machine may be shared: the load average is printed before and after.

All contenders run single-threaded (OPENBLAS_NUM_THREADS=1) and are timed in process CPU
time, taking turns within each repeat: figures per core.

Run: .venv/bin/python test/bench/bench_rls.py [--repeats 5]
"""
from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')  # one core for every contender

import numpy as np

from herd_ros.estimation import rls_kernels
from herd_ros.estimation.online_fit import OnlineHerdEstimator
from herd_ros.estimation.rls import HerdRLS

K, B = 36, 6
LAMBDA = 0.999


def numpy_loop_update(theta, P, H, y, lam):
    """Textbook RLS for one agent: K = P Hᵀ (λI + H P Hᵀ)⁻¹, θ += K e, P = (P − K H P)/λ."""
    PHt = P @ H.T
    gain = np.linalg.solve(lam * np.eye(2) + H @ PHt, PHt.T).T
    theta += gain @ (y - H @ theta)
    P -= gain @ (H @ P)
    P /= lam
    return theta, P


def load_average() -> str:
    """The 1, 5 and 15 minute load averages (the machine may be shared)."""
    return ' '.join(f'{x:.2f}' for x in os.getloadavg())


def time_until(fn, min_seconds=0.2, min_calls=2):
    """CPU seconds of this process per call of fn (runs it until min_seconds of CPU time and
    min_calls are reached). CPU time, not wall time: on a shared machine the time this
    process waits for a core does not count (its cache and memory bandwidth still suffer)."""
    calls, start = 0, time.process_time()
    while True:
        fn()
        calls += 1
        el = time.process_time() - start
        if el >= min_seconds and calls >= min_calls:
            return el / calls


def contenders(n, p, rng):
    """name → (agents per call, one call), for the four contenders of a herd of n."""
    H = rng.normal(size=(n, 2, p))
    y = rng.normal(size=(n, 2))
    chunk = n if p <= 400 else 50
    Hs = [rng.normal(size=(chunk, 2, p)) for _ in range(4)]  # fresh rows every update
    out = {}
    for name, compiled in (('compiled', True), ('numpy', False)):
        rls = HerdRLS(chunk, p, forgetting=LAMBDA, p0=1e3, compiled=compiled)
        counter = iter(range(10 ** 9))

        def batched_step(rls=rls, counter=counter):
            rls.update(Hs[next(counter) % 4], y[:chunk])
        batched_step()  # warm-up (caches, and numba's compilation if its cache was cold)
        out[name] = (chunk, batched_step)
    sample = min(n, 20 if p < 200 else 3)
    loop_state = [(np.zeros(p), np.eye(p) * 1e3) for _ in range(sample)]

    def loop():
        for i in range(sample):
            numpy_loop_update(*loop_state[i], H[i], y[i], LAMBDA)
    out['loop'] = (sample, loop)
    try:
        from padasip.filters import FilterRLS  # benchmark-only dependency
    except ImportError:
        return out
    psample = min(n, 20 if p < 200 else 2)
    filters = [(FilterRLS(p, mu=LAMBDA, eps=1e-3), FilterRLS(p, mu=LAMBDA, eps=1e-3))
               for _ in range(psample)]

    def padasip_step():
        for i in range(psample):
            filters[i][0].adapt(y[i, 0], H[i, 0])
            filters[i][1].adapt(y[i, 1], H[i, 1])
    out['padasip'] = (psample, padasip_step)
    return out


def rates(n, p, repeats, rng):
    """Median agent-updates per second (CPU time) of each contender; the contenders take
    turns within every repeat, so a change of the machine's load hits them all alike."""
    runs = contenders(n, p, rng)
    samples = {name: [] for name in ('compiled', 'numpy', 'loop', 'padasip')}
    for _ in range(repeats):
        for name, (agents, step) in runs.items():
            samples[name].append(agents / time_until(step))
    return {name: float(np.median(v)) if v else np.nan for name, v in samples.items()}


def cpu_share_1000_shared(repeats, rng, compiled=True, n=1000, law='shared',
                          alignment=False):
    """Process time per 1 Hz snapshot of ``n`` animals (default 1 000 with the shared law;
    ``alignment``: with the velocity alignment's columns, 4 bumps over 40 m), as a share
    of one core: the estimator's live throughput — what the node does per snapshot, the
    update and the one-step prediction it publishes."""
    agents = [f'a{k}' for k in range(n)]
    est = OnlineHerdEstimator(agents, 1.0, law, (6, 6), (-500, 500, -500, 500),
                              forgetting=LAMBDA, alignment=alignment)
    est.rls.compiled = compiled
    p = rng.uniform(-500, 500, size=(n, 2))
    v = rng.normal(scale=0.5, size=(n, 2))
    t = 0.0
    for _ in range(3):  # prime the chain
        p = p + v + rng.normal(scale=0.1, size=(n, 2))
        est.add_snapshot(t, p)
        t += 1.0
    shares = []
    for _ in range(repeats):
        c0 = time.process_time()
        steps = 5 if n >= 1000 else 200
        for _ in range(steps):
            p = p + v + rng.normal(scale=0.1, size=(n, 2))
            est.add_snapshot(t, p)
            est.predict()
            t += 1.0
        shares.append((time.process_time() - c0) / steps)  # CPU seconds per 1 s of herd time
    return float(np.median(shares))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--repeats', type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    cases = [('pairwise', 3), ('pairwise', 30), ('pairwise', 300),
             ('shared', 1000), ('shared', 10000)]
    print(f'load average before: {load_average()}')
    if rls_kernels.compiled_update() is None:
        print('numba not available: the "compiled" column is the numpy path')
    else:
        print(f'compiled kernel: numba {rls_kernels.numba.__version__} (compile time excluded)')
    print(f'RLS agent-updates per CPU second (median of {args.repeats} repeats; K = {K}, B = {B})')
    print(f'{"law":>9} {"agents":>7} {"params":>7} {"compiled":>10} {"numpy":>9} '
          f'{"numpy loop":>11} {"padasip":>9} {"vs loop":>8} {"vs padasip":>10} '
          f'{"numpy vs padasip":>16}')
    for law, n in cases:
        p = 1 + 2 * (n - 1) + 2 * K if law == 'pairwise' else 1 + B + 2 * K
        r = rates(n, p, args.repeats, rng)
        print(f'{law:>9} {n:7d} {p:7d} {r["compiled"]:10.0f} {r["numpy"]:9.0f} '
              f'{r["loop"]:11.0f} {r["padasip"]:9.1f} {r["compiled"] / r["loop"]:7.1f}x '
              f'{r["compiled"] / r["padasip"]:9.1f}x {r["numpy"] / r["padasip"]:15.1f}x')
    for compiled in (True, False):
        share = cpu_share_1000_shared(args.repeats, rng, compiled)
        print(f'1 000 animals, shared law, 1 Hz, {"compiled" if compiled else "numpy":>8}: '
              f'{share * 1e3:5.1f} ms CPU per snapshot = {100 * share:4.1f} % of one core '
              f'(regressors + update + prediction)')
    print('the estimator with velocity alignment (issue 31): CPU per snapshot, compiled')
    for law, n in (('pairwise', 20), ('shared', 1000)):
        without, with_ = (cpu_share_1000_shared(args.repeats, rng, True, n, law, a)
                          for a in (False, True))
        print(f'{n:5d} animals, {law:>8} law: {without * 1e3:6.2f} ms without, '
              f'{with_ * 1e3:6.2f} ms with alignment ({100 * (with_ / without - 1):+.0f} %)')
    print(f'load average after: {load_average()}')
    print('reproduce: .venv/bin/python test/bench/bench_rls.py --repeats', args.repeats)


if __name__ == '__main__':
    main()
