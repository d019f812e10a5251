"""Benchmark: flocking steps per second for 50, 500 and 5 000 agents (medians), and the ratio
against a public MEAM 6240-style implementation at 50 agents when one is given.

A step is one control period of the full law (cKDTree neighbours, α + β + γ, one
semi-implicit Euler step), from the report's placement scaled to keep its density: N agents
uniform in a square of side 75·√(N/50) m, target from (20, 50) at 10 m/s, obstacle scenario
(one β obstacle), local-com γ. "with metrics" adds the six per-step metrics of all agents
and of the non-adversarial ones (what `herd-ros flock` computes).

Reference (never committed, never copied): set HERD_FLOCK_REFERENCE to a checkout of a
MEAM 6240-style Olfati-Saber implementation laid out like github.com/JAAACKL/swarm-flocking
(`Olfati-Saber 2D/run2D.py` with `generateRandomGraph2D(N, is_flocking)` and
`Graph2D.run_simulation(steps)`, per-agent Python objects, metrics every step). It runs in its
own process on 50 agents; the ratio is our steps/s (with metrics) over its steps/s.

    .venv/bin/python test/bench/bench_flocking.py
    HERD_FLOCK_REFERENCE=/path/to/swarm-flocking .venv/bin/python test/bench/bench_flocking.py
"""
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import numpy as np  # noqa: E402

from herd_ros.flocking import scenarios  # noqa: E402
from herd_ros.flocking.olfati_saber import FlockingParams  # noqa: E402

REPEATS = 5
SIZES = (50, 500, 5000)
SIM_SECONDS = {50: 4.0, 500: 1.0, 5000: 0.2}
REFERENCE_STEPS = 100

_REFERENCE_RUNNER = r'''
import contextlib, io, json, os, sys, time
import numpy as np
os.environ["MPLBACKEND"] = "Agg"
folder = sys.argv[1]
sys.path.insert(0, folder)
os.chdir(folder)
from run2D import generateRandomGraph2D
np.random.seed(0)
G = generateRandomGraph2D(int(sys.argv[2]), True)
steps = int(sys.argv[3])
with contextlib.redirect_stdout(io.StringIO()):
    t0 = time.perf_counter()
    G.run_simulation(steps)
    elapsed = time.perf_counter() - t0
print(json.dumps({"steps_per_s": steps / elapsed}))
'''


def our_steps_per_second(n_agents: int, with_metrics: bool) -> float:
    scale = np.sqrt(n_agents / 50)
    old_box = scenarios.PLACEMENT_BOX
    scenarios.PLACEMENT_BOX = 75.0 * scale
    try:
        scenario = scenarios.make_scenario('obstacle')
        duration = SIM_SECONDS[n_agents]
        t0 = time.perf_counter()
        scenarios.simulate(scenario, FlockingParams(), n_agents=n_agents, seed=0,
                           duration=duration, substeps=1, record_every=10 ** 6,
                           with_metrics=with_metrics)
        elapsed = time.perf_counter() - t0
    finally:
        scenarios.PLACEMENT_BOX = old_box
    return round(duration / scenarios.DT) / elapsed


def reference_steps_per_second(checkout: Path, n_agents: int = 50):
    folder = checkout / 'Olfati-Saber 2D'
    if not (folder / 'run2D.py').exists():
        return None, f'{folder}/run2D.py not found'
    env = dict(os.environ, MPLBACKEND='Agg')
    proc = subprocess.run([sys.executable, '-c', _REFERENCE_RUNNER, str(folder), str(n_agents),
                           str(REFERENCE_STEPS)], capture_output=True, text=True, env=env,
                          timeout=900)
    if proc.returncode:
        return None, 'reference failed: ' + (proc.stderr.strip().splitlines() or ['?'])[-1]
    return json.loads(proc.stdout.strip().splitlines()[-1])['steps_per_s'], None


def main() -> int:
    print(f'flocking steps per second (median of {REPEATS}; control law + Euler step, '
          f'obstacle scenario, local-com)')
    print(f'{"agents":>7} {"law only":>12} {"with metrics":>14}')
    ours_50 = None
    for n in SIZES:
        law = statistics.median(our_steps_per_second(n, False) for _ in range(REPEATS))
        full = statistics.median(our_steps_per_second(n, True) for _ in range(REPEATS))
        if n == 50:
            ours_50 = full
        print(f'{n:>7} {law:>12.0f} {full:>14.0f}')
    checkout = os.environ.get('HERD_FLOCK_REFERENCE')
    if not checkout:
        print('reference comparison skipped: HERD_FLOCK_REFERENCE is not set (a checkout of a '
              'MEAM 6240-style implementation, e.g. github.com/JAAACKL/swarm-flocking)')
    else:
        runs = [reference_steps_per_second(Path(checkout)) for _ in range(3)]
        errors = [e for _, e in runs if e]
        if errors:
            print(f'reference comparison skipped: {errors[0]}')
        else:
            ref = statistics.median(v for v, _ in runs)
            print(f'reference ({checkout}), 50 agents, with its metrics: {ref:.1f} steps/s '
                  f'(median of 3 × {REFERENCE_STEPS} steps); ours/reference = {ours_50 / ref:.0f}×')
    print('reproduce: [HERD_FLOCK_REFERENCE=/path/to/checkout] '
          '.venv/bin/python test/bench/bench_flocking.py')
    return 0


if __name__ == '__main__':
    sys.exit(main())
