"""`record` node: record named topics to a rosbag2 (mcap), surviving ``kill -9``.

Each topic in ``topics`` is subscribed as soon as a publisher of it appears in the graph
(checked every ``discovery_period_s``), with the type that publisher offers and a QoS
adapted to the publishers (reliable only if all of them are, transient-local only if all
of them are; keep-last ``qos_depth``). Messages arrive raw (``raw=True``: CDR bytes) and
are written unchanged with their receive time on the node clock (``use_sim_time`` makes
that ``/clock``); receive times are kept non-decreasing. The publishers' QoS profiles are
stored as the topic's ``offered_qos_profiles``, so ``replay`` offers the same.

Crash safety (mcap): the bag is written with :class:`herd_ros.io.bags.BagWriter` in
crash-safe mode — ``metadata.yaml`` exists from the start, and every
``flush_period_s`` (and every ``flush_messages`` messages) the messages so far go to the
file as one chunk followed by a closing footer, and metadata.yaml is rewritten. A
``kill -9`` loses at most the messages of the last ``flush_period_s``; the bag opens with
rosbags, the ``mcap`` library or ``herd-ros`` as it is, with no repair step. SIGINT or
SIGTERM close the bag properly (indexed summary). ``storage: sqlite3`` is accepted but is
only written at close (not crash-safe).
"""
from __future__ import annotations

import importlib
import sys
import time
from pathlib import Path

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from herd_ros.errors import HerdInputError
from herd_ros.io.bags import BagWriter
from herd_ros.nodes.ros_common import (ParameterError, declare_parameters,
                                       describe_remaining_parameters, exit_process, run_node,
                                       wall_timer)
from herd_ros.params.record import PARAMS as DEFAULTS


def default_bag_name(now: float | None = None) -> str:
    """``rosbag2_YYYY_MM_DD-HH_MM_SS`` (local time), as ``ros2 bag record`` names bags."""
    return time.strftime('rosbag2_%Y_%m_%d-%H_%M_%S', time.localtime(now))


def bag_qos(profile: QoSProfile):
    """rclpy QoS -> ``rosbags.interfaces.Qos`` (the rmw enum values are shared)."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, \
        QosReliability, QosTime

    def duration(d):
        ns = int(d.nanoseconds)
        return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)
    return Qos(QosHistory(int(profile.history)), int(profile.depth),
               QosReliability(int(profile.reliability)), QosDurability(int(profile.durability)),
               duration(profile.deadline), duration(profile.lifespan),
               QosLiveliness(int(profile.liveliness)),
               duration(profile.liveliness_lease_duration),
               bool(profile.avoid_ros_namespace_conventions))


def subscription_qos(offered: list[QoSProfile], depth: int) -> QoSProfile:
    """Reliable if every publisher is, transient-local if every publisher is."""
    reliable = bool(offered) and all(q.reliability == ReliabilityPolicy.RELIABLE
                                     for q in offered)
    latched = bool(offered) and all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL
                                    for q in offered)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class RecordConfig:
    """Validated record parameters (raises :class:`ParameterError` naming the parameter)."""

    def __init__(self, p: dict):
        self.topics = [t if t.startswith('/') else '/' + t for t in map(str, p['topics'])]
        if not self.topics or len(set(self.topics)) != len(self.topics):
            raise ParameterError('topics: give the topics to record (a non-empty list of '
                                 'distinct names)')
        self.bag = Path(str(p['bag']).strip() or default_bag_name())
        if self.bag.exists():
            raise ParameterError(f'bag: {self.bag} already exists; record writes a new bag')
        if p['storage'] not in ('mcap', 'sqlite3'):
            raise ParameterError(f'storage must be mcap or sqlite3, got {p["storage"]!r}')
        self.storage = p['storage']
        for name in ('flush_period_s', 'discovery_period_s', 'progress_period_s'):
            if not isinstance(p[name], (int, float)) or not p[name] > 0:
                raise ParameterError(f'{name} must be a number > 0, got {p[name]!r}')
        for name in ('flush_messages', 'qos_depth'):
            if not isinstance(p[name], int) or p[name] < 1:
                raise ParameterError(f'{name} must be an integer ≥ 1, got {p[name]!r}')
        self.flush_period_s = float(p['flush_period_s'])
        self.discovery_period_s = float(p['discovery_period_s'])
        self.progress_period_s = float(p['progress_period_s'])
        self.flush_messages = int(p['flush_messages'])
        self.qos_depth = int(p['qos_depth'])


class Record(Node):
    """Subscribes to the requested topics as they appear and writes what arrives."""

    def __init__(self):
        super().__init__('record')
        self.cfg = cfg = RecordConfig(declare_parameters(self, DEFAULTS))
        describe_remaining_parameters(self, 'not a record parameter (ignored)')
        try:
            self.bag = BagWriter(cfg.bag, storage=cfg.storage,
                                 crash_safe=cfg.storage == 'mcap').open()
        except (HerdInputError, OSError) as exc:
            raise ParameterError(f'bag: {exc}') from None
        self.subs = {}
        self.counts = {t: 0 for t in cfg.topics}
        self.last_ns = 0
        self.unflushed = 0
        self.get_logger().info(f'recording {", ".join(cfg.topics)} to {cfg.bag} '
                               f'({cfg.storage})')
        wall_timer(self, cfg.discovery_period_s, self.discover)
        wall_timer(self, cfg.flush_period_s, self.flush)
        wall_timer(self, cfg.progress_period_s, self.report)
        self.discover()

    def discover(self):
        """Subscribe to the topics that have appeared (with their types and QoS)."""
        pending = [t for t in self.cfg.topics if t not in self.subs]
        if not pending:
            return
        types = dict(self.get_topic_names_and_types())
        for topic in pending:
            if topic not in types:
                continue
            msgtype = types[topic][0]
            offered = [i.qos_profile for i in self.get_publishers_info_by_topic(topic)]
            if not offered:
                continue
            try:
                pkg, kind, name = msgtype.split('/')
                cls = getattr(importlib.import_module(f'{pkg}.{kind}'), name)
                self.bag.add_topic(topic, msgtype, [bag_qos(q) for q in offered])
            except (ValueError, ImportError, AttributeError, HerdInputError) as exc:
                self.get_logger().error(f'{topic}: cannot record type {msgtype}: {exc}')
                self.subs[topic] = None
                continue
            qos = subscription_qos(offered, self.cfg.qos_depth)
            self.subs[topic] = self.create_subscription(
                cls, topic, lambda data, t=topic: self.on_message(t, data), qos, raw=True)
            self.get_logger().info(f'subscribed {topic} [{msgtype}] '
                                   f'{qos.reliability.name.lower()}/'
                                   f'{qos.durability.name.lower()}')

    def on_message(self, topic: str, data: bytes):
        """Write one serialized message to the bag, stamped with the node clock."""
        t_ns = max(self.get_clock().now().nanoseconds, self.last_ns)
        self.last_ns = t_ns
        self.bag.write_raw(topic, t_ns, data)
        self.counts[topic] += 1
        self.unflushed += 1
        if self.unflushed >= self.cfg.flush_messages:
            self.flush()

    def flush(self):
        """Flush what was written since the last flush."""
        if self.unflushed:
            self.bag.flush()
            self.unflushed = 0

    def report(self):
        """Log how many messages were recorded, per topic."""
        self.get_logger().info(f'recorded {sum(self.counts.values())} messages: ' + ', '.join(
            f'{t} {n}' for t, n in self.counts.items()))

    def on_shutdown(self):
        """Close the bag and say so."""
        self.bag.close()
        # printed, not logged: the context may already be shut down (no /rosout)
        print(f'record: closed {self.cfg.bag}: {sum(self.counts.values())} messages',
              file=sys.stderr)


def main(args=None):
    """Run the node (``ros2 run herd_ros NODE``); exits with its status."""
    exit_process(run_node(Record, args=args))


if __name__ == '__main__':
    main()
