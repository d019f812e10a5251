"""`gps_ingest` through DDS: N collars at 1 Hz for a minute (issues 3 and 12).

Three processes on this machine, loopback-only discovery, a domain of their own:

* the ``gps_ingest`` node (the installed console script), one run per executor;
* a publisher process (this script, ``--role publisher``), collar k publishing at phase k/N
  of every second, each fix stamped with its publish wall time (live collars: data time =
  wall time): ``--topics per-collar``, one NavSatFix publisher per collar on
  ``/herd/<agent>/fix``; ``--topics shared``, a gateway's one publisher on ``/herd/fix``,
  the collar in ``header.frame_id`` (the node's ``fix_topic`` / ``odom_topic``);
* this process: receives every Odometry (``/herd/<agent>/odom`` or ``/herd/odom``), reading
  only its stamp and child frame from the serialized message, and, after the run, the node's
  ``/diagnostics``.

Latency = wall time an Odometry is received here − its stamp (= the fix's publish time), so
it includes DDS both ways, the node, and this process' own queueing. Loss: every published
fix must be counted by the node (accepted or rejected: the totals of its final diagnostics)
and every accepted one must arrive here as Odometry.

    .venv/bin/python test/bench/bench_ingest_dds.py [--collars 1000] [--seconds 60]
        [--executors events,single_threaded] [--topics per-collar|shared]
"""
import argparse
import json
import os
import random
import shutil
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
DATUM = (46.8, 7.15, 550.0)
SHARED_FIX, SHARED_ODOM = '/herd/fix', '/herd/odom'


def agents_of(n):
    return [f'cow_{k:04d}' for k in range(n)]


def cpu_seconds(pid):
    """utime + stime of a process (s)."""
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def bench_env() -> dict:
    """Environment of the benchmark's processes: DDS on this machine (loopback discovery, a
    domain of the run's own), unbuffered output. The nodes are the installed console scripts
    running the installed package (``make bench`` reinstalls it from this checkout first),
    with the collar kernels it was built with; the publisher imports this checkout itself."""
    env = dict(os.environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['ROS_STATIC_PEERS'] = ''
    env.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 100)))
    env.pop('PYTHONPATH', None)
    env['PYTHONUNBUFFERED'] = '1'
    return env


# -- publisher process -----------------------------------------------------------------------
def run_publisher(n, seconds, rate, shared):
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import NavSatFix, NavSatStatus

    from herd_ros.ingest.geodesy import enu_to_geodetic

    rclpy.init()
    node = rclpy.create_node('bench_collars')
    agents = agents_of(n)
    if shared:
        pubs = [node.create_publisher(NavSatFix, SHARED_FIX, qos_profile_sensor_data)] * n
    else:
        pubs = [node.create_publisher(NavSatFix, f'/herd/{a}/fix', qos_profile_sensor_data)
                for a in agents]
    msgs = []
    for a in agents:                     # one message per collar, refilled at each fix
        msg = NavSatFix()
        msg.header.frame_id = a
        msg.status.status = NavSatStatus.STATUS_FIX
        msg.altitude = float('nan')
        msgs.append(msg)
    deadline = time.monotonic() + 1800     # 10 000 collars: the node takes ~3 min to build
    while time.monotonic() < deadline:
        if all(p.get_subscription_count() > 0 for p in pubs):
            break
        time.sleep(0.2)
    else:
        print(json.dumps({'error': 'gps_ingest never subscribed'}), flush=True)
        return 1
    import gc
    gc.collect()
    gc.freeze()
    print(json.dumps({'ready': True}), flush=True)
    sys.stdin.readline()        # the measurer's go: it has matched every odometry topic too
    rng = np.random.default_rng(0)
    home = rng.uniform(-500, 500, (n, 2))
    period = 1.0 / rate
    sent = np.zeros(n, dtype=int)
    start = time.time() + 1.0
    total = int(seconds * rate) * n
    for j in range(total):
        k, cycle = j % n, j // n
        if k == 0:                       # this cycle's positions, all collars at once
            z = home + rng.normal(0, 2.0, (n, 2))
            lat, lon, _ = enu_to_geodetic(z[:, 0], z[:, 1], np.zeros(n), *DATUM)
            lat, lon = lat.tolist(), lon.tolist()
        due = start + cycle * period + k * period / n
        delay = due - time.time()
        if delay > 0.002:
            time.sleep(delay)
        msg = msgs[k]
        ns = time.time_ns()
        msg.header.stamp.sec, msg.header.stamp.nanosec = ns // 10**9, ns % 10**9
        msg.latitude, msg.longitude = lat[k], lon[k]
        pubs[k].publish(msg)
        sent[k] += 1
    lag = time.time() - (start + seconds)
    print(json.dumps({'sent': sent.tolist(), 'lag_at_end_s': lag}), flush=True)
    time.sleep(2.0)
    node.destroy_node()
    rclpy.shutdown()
    return 0


# -- measuring process ------------------------------------------------------------------------
def odometry_stamp_and_child(data: bytes) -> tuple[float, str]:
    """Stamp (s) and child_frame_id of a serialized nav_msgs/Odometry (CDR, little endian:
    int32 sec, uint32 nanosec, frame_id string, child_frame_id string 4-aligned) -- read
    here with struct, independently of the node's codec."""
    sec, nanosec, n = struct.unpack_from('<iII', data, 4)
    at = 12 + n + (-(12 + n) % 4)            # body offset of the child's length
    m = struct.unpack_from('<I', data, 4 + at)[0]
    return sec + 1e-9 * nanosec, data[8 + at:8 + at + m - 1].decode()


class Measurer:
    """Receives every odometry (latency) and, once the publisher is done, the node's
    diagnostics (its totals). Converting a /diagnostics message of 1 000 collar statuses
    takes this process ~0.1 s, during which odometry waits: subscribed during the run, it
    would be counted as the node's latency."""

    def __init__(self, node, agents, shared):
        from nav_msgs.msg import Odometry
        self.node = node
        self.latency = []
        self.arrival = []
        self.received = dict.fromkeys(agents, 0)
        self.totals = None
        self.ticks = []          # (arrival, bytes) of every /herd/poses
        from geometry_msgs.msg import PoseArray
        node.create_subscription(PoseArray, '/herd/poses',
                                 lambda data: self.ticks.append((time.time(), len(data))), 100,
                                 raw=True)
        if shared:
            self.subscriptions = [node.create_subscription(
                Odometry, SHARED_ODOM, self.on_odom, 10 * len(agents), raw=True)]
        else:
            self.subscriptions = [node.create_subscription(Odometry, f'/herd/{a}/odom',
                                                           self.on_odom, 50, raw=True)
                                  for a in agents]

    def matched(self) -> bool:
        """Every odometry topic and /herd/poses has the node's publisher (discovery done
        both ways)."""
        return (all(s.get_publisher_count() > 0 for s in self.subscriptions)
                and self.node.count_publishers('/herd/poses') > 0)

    def listen_to_diagnostics(self):
        from diagnostic_msgs.msg import DiagnosticArray
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self.on_diag, 5)

    def on_odom(self, data):
        now = time.time()
        stamp, agent = odometry_stamp_and_child(data)
        self.latency.append(now - stamp)
        self.arrival.append(now)
        self.received[agent] += 1

    def on_diag(self, msg):
        for s in msg.status:
            if s.name == 'gps_ingest':
                v = {kv.key: kv.value for kv in s.values}
                self.totals = (int(v['fixes']), int(v['accepted']))


def run_once(n, seconds, rate, executor_name, env, shared=False):
    import rclpy
    from rclpy.experimental import EventsExecutor

    agents = agents_of(n)
    tmp = Path(tempfile.mkdtemp(prefix='bench_ingest_dds_'))
    params = tmp / 'gps_ingest.yaml'
    params.write_text('gps_ingest:\n  ros__parameters:\n'
                      f'    agents: [{", ".join(agents)}]\n'
                      f'    datum: [{", ".join(str(v) for v in DATUM)}]\n'
                      f'    dt: {1.0 / rate}\n    stale_after: {10.0 / rate}\n'
                      f'    executor: {executor_name}\n'
                      + (f'    fix_topic: {SHARED_FIX}\n    odom_topic: {SHARED_ODOM}\n'
                         if shared else ''))
    log = open(tmp / 'gps_ingest.log', 'w')
    node_proc = subprocess.Popen([str(Path(sys.executable).parent / 'gps_ingest'),
                                  '--ros-args', '--params-file', str(params)],
                                 env=env, stdout=log, stderr=subprocess.STDOUT)
    pub_proc, alive = None, False
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node('bench_measurer', context=context)
        measurer = Measurer(node, agents, shared)
        executor = EventsExecutor(context=context)
        executor.add_node(node)

        def spin_for(sec, until=None):
            end = time.monotonic() + sec
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=0.05)
                if until is not None and until():
                    return True
            return False

        t_setup = time.monotonic()
        pub_proc = subprocess.Popen([sys.executable, __file__, '--role', 'publisher',
                                     '--collars', str(n), '--seconds', str(seconds),
                                     '--rate', str(rate)]
                                    + (['--topics', 'shared'] if shared else []),
                                    env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                    text=True)
        lines = []
        threading.Thread(target=lambda: lines.extend(
            json.loads(x) for x in pub_proc.stdout if x.strip()), daemon=True).start()

        def publisher_said(key):
            return any(key in x for x in list(lines)) or pub_proc.poll() is not None

        spin_for(2000, lambda: publisher_said('ready') or publisher_said('error'))
        if not any('ready' in x for x in lines):
            raise RuntimeError(f'publisher failed: {lines}')
        # the first fixes must not wait for this process' own discovery of the node
        if not spin_for(1800, measurer.matched):
            raise RuntimeError('the odometry topics were never matched')
        setup_s = time.monotonic() - t_setup
        pub_proc.stdin.write('go\n')
        pub_proc.stdin.flush()
        import gc
        gc.collect()
        gc.freeze()     # this process' own full GC passes must not count as the node's latency
        cpu0, t0 = cpu_seconds(node_proc.pid), time.monotonic()
        spin_for(seconds + 600, lambda: publisher_said('sent'))
        run_s = time.monotonic() - t0
        cpu1 = cpu_seconds(node_proc.pid)
        measurer.listen_to_diagnostics()
        sent = next(x for x in lines if 'sent' in x)
        total_sent = int(sum(sent['sent']))
        # drain: wait until the node has accounted for every fix (or 20 s)
        spin_for(20, lambda: measurer.totals is not None
                 and measurer.totals[0] >= total_sent
                 and sum(measurer.received.values()) >= measurer.totals[1])
        spin_for(1.5)
        alive = node_proc.poll() is None
    finally:
        for proc in (pub_proc, node_proc):
            if proc is not None and proc.poll() is None:
                proc.send_signal(2)
                try:
                    proc.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        rclpy.shutdown(context=context)
        log.close()
    if alive:
        shutil.rmtree(tmp, ignore_errors=True)     # the node's log matters only if it died
    else:
        print(f'the node died; its log: {tmp / "gps_ingest.log"}', file=sys.stderr)
    counted, accepted = measurer.totals or (0, 0)
    received = sum(measurer.received.values())
    lat = np.array(measurer.latency) * 1e3
    arrival = np.array(measurer.arrival)
    steady = lat[arrival >= arrival.min() + 5.0] if len(lat) else lat
    return {'executor': executor_name, 'topics': 'shared' if shared else 'per-collar',
            'collars': n, 'sent': total_sent,
            'counted': counted, 'accepted': accepted, 'odom': received,
            'lost_to_node': total_sent - counted, 'lost_odom': accepted - received,
            'p50_ms': float(np.percentile(lat, 50)) if len(lat) else float('nan'),
            'p99_ms': float(np.percentile(lat, 99)) if len(lat) else float('nan'),
            'p99_steady_ms': (float(np.percentile(steady, 99)) if len(steady)
                              else float('nan')),
            'node_cpu': (cpu1 - cpu0) / run_s, 'setup_s': setup_s,
            'ticks': len(measurer.ticks),
            'tick_kb': measurer.ticks[-1][1] / 1024 if measurer.ticks else 0.0,
            'publisher_lag_s': sent['lag_at_end_s'], 'alive': alive}


#: ``make bench`` (no --collars): what issue 12 asks, in one run
SUITE = [(1000, 'per-collar', 'events'), (1000, 'per-collar', 'single_threaded'),
         (10000, 'shared', 'events')]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--role', choices=('bench', 'publisher'), default='bench')
    ap.add_argument('--collars', type=int, default=None,
                    help='collars (default: the suite 1 000 per-collar with both executors, '
                         '10 000 shared with the events executor)')
    ap.add_argument('--seconds', type=float, default=60.0)
    ap.add_argument('--rate', type=float, default=1.0, help='fixes per collar per second')
    ap.add_argument('--executors', default='events,single_threaded',
                    help='with --collars: the executors to run, one run each')
    ap.add_argument('--topics', choices=('per-collar', 'shared'), default='per-collar',
                    help=f'with --collars: a topic per collar, or {SHARED_FIX} and '
                         f'{SHARED_ODOM} for all')
    args = ap.parse_args(argv)
    shared = args.topics == 'shared'
    if args.role == 'publisher':
        try:
            return run_publisher(args.collars, args.seconds, args.rate, shared)
        except KeyboardInterrupt:
            return 0
    env = bench_env()
    os.environ.update({k: env[k] for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE',
                                           'ROS_STATIC_PEERS', 'ROS_DOMAIN_ID')})
    if args.collars is None:
        runs = SUITE
    else:
        runs = [(args.collars, args.topics, name.strip()) for name in args.executors.split(',')]
    rows = []
    for collars, topics, name in runs:
        r = run_once(collars, args.seconds, args.rate, name, env, topics == 'shared')
        rows.append(r)
        if not r['alive']:
            print(f'warning: gps_ingest ({name}) was not alive at the end', file=sys.stderr)
        if r['publisher_lag_s'] > 1.0:
            print(f'warning: the publisher fell {r["publisher_lag_s"]:.1f} s behind: the '
                  f'offered rate was lower than asked', file=sys.stderr)
    print(f'{"executor":>16} {"topics":>10} {"collars":>7} {"fix/s":>6} {"sent":>7} '
          f'{"lost->node":>10} {"lost->odom":>10} {"p50 ms":>8} {"p99 ms":>8} '
          f'{"p99 >5 s":>8} {"node cpu":>8} {"setup s":>7} {"ticks":>6} {"tick kB":>7}')
    for r in rows:
        print(f'{r["executor"]:>16} {r["topics"]:>10} {r["collars"]:>7} '
              f'{r["collars"] * args.rate:>6.0f} {r["sent"]:>7} {r["lost_to_node"]:>10} '
              f'{r["lost_odom"]:>10} {r["p50_ms"]:>8.1f} {r["p99_ms"]:>8.1f} '
              f'{r["p99_steady_ms"]:>8.1f} {100 * r["node_cpu"]:>7.0f}% {r["setup_s"]:>7.1f} '
              f'{r["ticks"]:>6} {r["tick_kb"]:>7.0f}')
    print(f'one run of {args.seconds:g} s each (p50, p99: fix->odom latency over every fix; '
          f'p99 >5 s: over the fixes received after the first 5 s; node cpu: share of one '
          f'core; ticks: /herd/poses snapshots received here, tick kB: the last one\'s '
          f'size); reproduce with: .venv/bin/python test/bench/bench_ingest_dds.py '
          + ('' if args.collars is None else
             f'--collars {args.collars} --executors {args.executors} --topics {args.topics} ')
          + f'--seconds {args.seconds:g}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
