"""Benchmark: imitation pipeline on the paper case (issue 7, acceptance 5).

C, S(e=2), A with k = [1, 1, 1], v_max 7, r 5, 40 agents, Δt 0.05, 20 runs of 5 s, position
noise 5 % of v_max·Δt. Prints medians over repeats of the stages of ``learn_policy``:
neighbour pairs (shared by search and fit), radius search, gain fit (IV + SLSQP + v_max).

    .venv/bin/python test/bench/bench_imitation.py
"""
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from herd_ros.imitation.boids import ImitationPolicy, simulate_runs  # noqa: E402
from herd_ros.imitation.learning import learn_policy  # noqa: E402

REPEATS = 5


def main():
    truth = ImitationPolicy(['cohesion', 'separation2', 'alignment'], [1, 1, 1], 5.0, 7.0, 0.05)
    runs = simulate_runs(truth, n_agents=40, n_runs=20, duration=5.0,
                         noise_std=0.05 * 7 * 0.05, rng=1)
    rows, totals, fits = [], [], []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        fit = learn_policy(runs, truth.policies)
        totals.append(time.perf_counter() - t0)
        rows.append(fit.timings)
        fits.append(fit)
    print(f'imitation pipeline, paper case (40 agents x 20 runs x 101 steps), '
          f'median of {REPEATS}')
    print(f'{"stage":>16s}  {"median s":>9s}')
    for key in ('prepare', 'neighbour_pairs', 'radius_search', 'gain_fit'):
        print(f'{key:>16s}  {np.median([r[key] for r in rows]):9.3f}')
    print(f'{"total":>16s}  {np.median(totals):9.3f}')
    p = fits[-1].policy
    print('recovered gains', np.round(p.gains, 4).tolist(), f'r {p.radius:.3f}',
          f'v_max {p.v_max:.3f}')
    print('reproduce: .venv/bin/python test/bench/bench_imitation.py')
    return 0


if __name__ == '__main__':
    sys.exit(main())
