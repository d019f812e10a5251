"""Run every benchmark script ``test/bench/bench_*.py`` (or those named on the command line).

Each script is run in its own process with loopback-only DDS and prints its own table of
medians; see doc/results.md. Usage::

    make bench                       # all of them
    .venv/bin/python test/bench/run_all.py bench_fit.py
"""
import os
import random
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv):
    names = argv or sorted(p.name for p in HERE.glob('bench_*.py'))
    env = dict(os.environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['ROS_STATIC_PEERS'] = ''
    env.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 100)))
    failed = []
    for name in names:
        print(f'\n=== {name}', flush=True)
        t0 = time.perf_counter()
        rc = subprocess.call([sys.executable, str(HERE / name)], env=env)
        print(f'=== {name}: exit {rc} after {time.perf_counter() - t0:.1f} s', flush=True)
        if rc:
            failed.append(name)
    if failed:
        print('failed: ' + ', '.join(failed))
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
