"""Soak: the live ingest → estimator path, N collars at 1 Hz for 10 minutes; resident memory
of both nodes every 10 s (issue "scale and hardening", acceptance 5).

Processes on this machine, loopback-only discovery, a domain of their own: the installed
``gps_ingest`` and ``estimator`` console scripts (shared interaction law, the law for large
herds), and the collar publisher of ``bench_ingest_dds.py`` (N NavSatFix publishers, one fix
per collar per second, stamped with wall time as live collars are). Memory is read from
``/proc/<pid>/status`` (VmRSS); after a warm-up (the first ``--warmup`` seconds: numba
loads, DDS discovery settles, the estimator's running statistics fill) it must stay flat:
the spread (max − min) over the rest, relative to the median, is the figure reported.

    .venv/bin/python test/bench/bench_soak.py [--collars 1000] [--minutes 10]
"""
import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(HERE))
from bench_ingest_dds import DATUM, agents_of, bench_env, cpu_seconds  # noqa: E402


def rss_mib(pid):
    with open(f'/proc/{pid}/status') as f:
        for line in f:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024.0
    return float('nan')


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--collars', type=int, default=1000)
    ap.add_argument('--minutes', type=float, default=10.0)
    ap.add_argument('--sample-s', type=float, default=10.0)
    ap.add_argument('--warmup', type=float, default=120.0,
                    help='seconds of the run left out of the flatness figure')
    args = ap.parse_args(argv)
    env = bench_env()
    tmp = Path(tempfile.mkdtemp(prefix='bench_soak_'))
    env['ROS_HOME'] = str(tmp)
    agents = agents_of(args.collars)
    seconds = 60.0 * args.minutes
    params = tmp / 'soak.yaml'
    agent_list = ', '.join(agents)
    params.write_text(
        'gps_ingest:\n  ros__parameters:\n'
        f'    agents: [{agent_list}]\n'
        f'    datum: [{", ".join(str(v) for v in DATUM)}]\n'
        '    dt: 1.0\n    stale_after: 10.0\n    diagnostics_period_s: 10.0\n'
        'estimator:\n  ros__parameters:\n'
        f'    agents: [{agent_list}]\n'
        '    dt: 1.0\n    law: shared\n    interaction_radius: 50.0\n'
        '    field_grid: [2, 2]\n    field_bounds: [-600.0, 600.0, -600.0, 600.0]\n'
        "    checkpoint_path: ''\n    diagnostics_period_s: 10.0\n")
    bin_dir = Path(sys.executable).parent
    procs, logs = {}, {}
    for name in ('gps_ingest', 'estimator'):
        logs[name] = open(tmp / f'{name}.log', 'w')
        procs[name] = subprocess.Popen([str(bin_dir / name), '--ros-args', '--params-file',
                                        str(params)], env=env, stdout=logs[name],
                                       stderr=subprocess.STDOUT)
    pub = subprocess.Popen([sys.executable, str(HERE / 'bench_ingest_dds.py'), '--role',
                            'publisher', '--collars', str(args.collars), '--seconds',
                            str(seconds)], env=env, stdout=subprocess.PIPE, text=True)
    lines = []
    threading.Thread(target=lambda: lines.extend(json.loads(x) for x in pub.stdout
                                                 if x.strip()), daemon=True).start()
    t_setup = time.monotonic()
    while not any('ready' in x or 'error' in x for x in lines) and pub.poll() is None:
        time.sleep(0.5)
    if not any('ready' in x for x in lines):
        print(f'publisher failed: {lines}', file=sys.stderr)
        return 1
    setup_s = time.monotonic() - t_setup
    print(f'{args.collars} collars subscribed after {setup_s:.0f} s; soaking for '
          f'{seconds:.0f} s, resident memory every {args.sample_s:g} s', flush=True)
    t0 = time.monotonic()
    cpu0 = {n: cpu_seconds(p.pid) for n, p in procs.items()}
    samples = []                        # (t, {node: MiB})
    next_sample = t0
    while pub.poll() is None and time.monotonic() - t0 < seconds + 120:
        now = time.monotonic()
        if now >= next_sample:
            row = {n: rss_mib(p.pid) for n, p in procs.items() if p.poll() is None}
            samples.append((now - t0, row))
            print(f'  {now - t0:6.0f} s  ' + '  '.join(f'{n} {v:7.1f} MiB'
                                                      for n, v in row.items()), flush=True)
            next_sample += args.sample_s
        time.sleep(0.2)
    run_s = time.monotonic() - t0
    cpu = {n: (cpu_seconds(p.pid) - cpu0[n]) / run_s for n, p in procs.items()
           if p.poll() is None}
    alive = {n: p.poll() is None for n, p in procs.items()}
    for p in procs.values():
        if p.poll() is None:
            p.send_signal(2)
    for p in procs.values():
        try:
            p.wait(timeout=15)
        except subprocess.TimeoutExpired:
            p.kill()
    for f in logs.values():
        f.close()
    if all(alive.values()):
        shutil.rmtree(tmp, ignore_errors=True)     # the nodes' logs matter only if one died
    else:
        print(f'a node died; the logs: {tmp}', file=sys.stderr)
    sent = next((x for x in lines if 'sent' in x), {})
    print(f'\n{"node":>10} {"RSS after warm-up: min":>22} {"median":>8} {"max":>8} '
          f'{"spread":>8} {"cpu":>6}')
    ok = True
    for name in procs:
        vals = np.array([row[name] for t, row in samples if t >= args.warmup and name in row])
        if len(vals) == 0:
            print(f'{name:>10} no samples after warm-up')
            ok = False
            continue
        spread = (vals.max() - vals.min()) / np.median(vals)
        ok &= spread < 0.05 and alive[name]
        print(f'{name:>10} {vals.min():>18.1f} MiB {np.median(vals):>8.1f} {vals.max():>8.1f} '
              f'{100 * spread:>7.1f}% {100 * cpu.get(name, float("nan")):>5.0f}%')
    print(f'{args.collars} collars x 1 Hz for {seconds:.0f} s ({sum(sent.get("sent", [])):d} '
          f'fixes; publisher lag at the end {sent.get("lag_at_end_s", float("nan")):.1f} s); '
          f'nodes alive at the end: {alive}; warm-up {args.warmup:g} s left out. Reproduce: '
          f'.venv/bin/python test/bench/bench_soak.py --collars {args.collars} '
          f'--minutes {args.minutes:g}')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
