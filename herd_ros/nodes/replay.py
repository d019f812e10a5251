"""`replay` node: play a rosbag2 (mcap or sqlite3) onto its topics, as recorded.

Messages are republished as the CDR bytes stored in the bag (``Publisher.publish(bytes)``),
so no message is converted and any type rclpy can import plays. Timing: message k is sent
at wall instant ``t0 + (t_k − t_first) / rate`` where ``t_k`` is its receive time in the
bag and ``t0`` the (monotonic) instant the pass started — every message is scheduled
against that fixed origin, so sleep errors never accumulate. Messages go out in bag order.

``/clock`` (rosgraph_msgs/Clock, when ``publish_clock``) carries the bag time: just before
each message and at ``clock_rate_hz`` in between, so ``use_sim_time`` nodes downstream run
on bag time (slowed or sped up with ``rate``); each loop pass jumps it back to the start.

QoS of each publisher: the first profile the bag recorded for the topic
(``offered_qos_profiles`` in metadata.yaml / the mcap channel) when ``qos_from_bag`` and
present (reliability, durability, history, depth); otherwise reliable, volatile,
keep-last ``default_qos_depth`` (100). Reliable is the default for every type, NavSatFix
included, because a reliable publisher serves both reliable and best-effort subscribers
while a best-effort one serves only the latter — and a replay should not drop fixes.
Set ``default_qos: sensor_data`` for best-effort, depth-5 publishers.

At the end of the bag (unless ``loop``) the node waits for reliable subscribers to
acknowledge and exits with status 0. Bad parameters exit with status 2 and one line.
"""
from __future__ import annotations

import importlib
import threading
import time

from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                       qos_profile_sensor_data)
from rosgraph_msgs.msg import Clock

from herd_ros.errors import HerdInputError
from herd_ros.io.bags import bag_info, read_raw_messages
from herd_ros.nodes.ros_common import (LiveParameters, ParameterError, declare_parameters,
                                       describe_remaining_parameters, exit_process,
                                       number_problem, run_node, seconds_to_stamp)
from herd_ros.params.replay import PARAMS as DEFAULTS, ReplayConfig


def message_class(msgtype: str):
    """``'sensor_msgs/msg/NavSatFix'`` -> the rclpy message class."""
    try:
        pkg, kind, name = msgtype.split('/')
        return getattr(importlib.import_module(f'{pkg}.{kind}'), name)
    except (ValueError, ImportError, AttributeError):
        raise ParameterError(f'message type {msgtype!r} of the bag cannot be imported in '
                             f'this Python environment') from None


def wall_schedule(t_ns: int, t_first_ns: int, t0_wall: float, rate: float) -> float:
    """Wall (monotonic) instant at which a message received at bag time ``t_ns`` plays:
    ``t0_wall + (t_ns − t_first_ns)·1e-9 / rate`` (fixed origin: no drift)."""
    return t0_wall + (t_ns - t_first_ns) * 1e-9 / rate


def qos_profile(recorded, default: str, depth: int) -> QoSProfile:
    """rclpy QoS from the first recorded ``rosbags.interfaces.Qos`` (enum values are the
    rmw ones), else the default described in the module docstring."""
    if recorded:
        q = recorded[0]
        rel, dur, hist = q.reliability.value, q.durability.value, q.history.value
        return QoSProfile(
            history=HistoryPolicy(hist) if hist in (1, 2) else HistoryPolicy.KEEP_LAST,
            depth=max(int(q.depth), depth) if hist != 2 else depth,
            reliability=ReliabilityPolicy(rel) if rel in (1, 2) else ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy(dur) if dur in (1, 2) else DurabilityPolicy.VOLATILE)
    if default == 'sensor_data':
        return qos_profile_sensor_data
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


class Replay(Node):
    """Publishers per bag topic, a player thread, and a clean exit at the end."""

    def __init__(self):
        super().__init__('replay')
        self.cfg = cfg = ReplayConfig(declare_parameters(self, DEFAULTS))
        try:
            self.info = info = bag_info(cfg.bag)
        except HerdInputError as exc:
            raise ParameterError(f'bag: {exc}') from None
        unknown = sorted(set(cfg.topics) - set(info.topics))
        if unknown:
            raise ParameterError(f'topics: not in {cfg.bag}: {", ".join(unknown)} '
                                 f'(bag topics: {", ".join(sorted(info.topics))})')
        self.topics = cfg.topics or sorted(info.topics)
        self.start_ns = info.start_ns + int(round(cfg.start_offset * 1e9))
        if info.message_count and self.start_ns > info.end_ns:
            raise ParameterError(f'start_offset {cfg.start_offset} s is past the end of the '
                                 f'bag ({info.duration_s:.3f} s long)')
        self.total = sum(info.topics[t][1] for t in self.topics)
        self.pubs = {}
        for topic in self.topics:
            msgtype = info.topics[topic][0]
            qos = qos_profile(info.offered_qos.get(topic) if cfg.qos_from_bag else None,
                              cfg.default_qos, cfg.default_qos_depth)
            out = cfg.remap.get(topic, topic)
            self.pubs[topic] = self.create_publisher(message_class(msgtype), out, qos)
            self.get_logger().info(
                f'{topic} -> {out} [{msgtype}] {info.topics[topic][1]} msgs, '
                f'{qos.reliability.name.lower()}/{qos.durability.name.lower()} depth '
                f'{qos.depth}')
        self.clock_pub = (self.create_publisher(Clock, '/clock', 10)
                          if cfg.publish_clock else None)
        self.get_logger().info(
            f'playing {cfg.bag}: {self.total} messages over {info.duration_s:.3f} s of bag '
            f'time at rate {cfg.rate:g} from offset {cfg.start_offset:g} s'
            f'{" (looping)" if cfg.loop else ""}')
        describe_remaining_parameters(self, 'not a replay parameter (ignored)')
        LiveParameters(self, self._validate_live, self._apply_live)
        self._stop = threading.Event()
        self.finished = threading.Event()   # set when playback is over (composed graphs wait)
        self._player = threading.Thread(target=self._run, name='replay', daemon=True)
        self._player.start()

    # -- live parameters (rate, progress_period_s) --------------------------------------
    def _validate_live(self, name, value):
        return number_problem(value)

    def _apply_live(self, name, value):
        setattr(self.cfg, name, float(value))     # the player thread reads it per message

    # -- player thread ---------------------------------------------------------------
    def _run(self):
        try:
            if self._wait_for_subscribers():
                passes = 0
                while not self._stop.is_set():
                    self._play_once(passes)
                    passes += 1
                    if not self.cfg.loop:
                        break
                if not self._stop.is_set():
                    self._drain()
        except Exception as exc:  # noqa: BLE001 - the player must report, never hang
            if not self._stop.is_set():
                self.get_logger().error(f'playback failed: {exc.__class__.__name__}: {exc}')
        finally:
            self.finished.set()
            if not self._stop.is_set() and self.cfg.exit_when_done:
                self.context.try_shutdown()      # ends the spin in run_node: exit 0

    def _wait_for_subscribers(self) -> bool:
        need = self.cfg.wait_for_subscribers
        if need <= 0:
            return True
        self.get_logger().info(f'waiting for {need} subscriber(s) on every topic')
        while not self._stop.is_set():
            if all(p.get_subscription_count() >= need for p in self.pubs.values()):
                return True
            self._stop.wait(0.05)
        return False

    def _play_once(self, pass_index: int):
        cfg = self.cfg
        clock_period = 1.0 / cfg.clock_rate_hz
        t_first = t0 = None
        sent = 0
        next_report = time.monotonic() + cfg.progress_period_s
        for topic, _, t_ns, data in read_raw_messages(cfg.bag, set(self.topics),
                                                      self.start_ns):
            if t_first is None:
                t_first, t0, rate = t_ns, time.monotonic(), cfg.rate
            while True:                                    # wait, ticking /clock
                now = time.monotonic()
                if cfg.rate != rate:                       # ros2 param set rate: the bag
                    t_first += int((now - t0) * rate * 1e9)     # time reached so far is
                    t0, rate = now, cfg.rate                     # kept, the pace changes
                due = wall_schedule(t_ns, t_first, t0, rate)
                if now >= due:
                    break
                if self.clock_pub is not None:
                    self._publish_clock(t_first + int((now - t0) * rate * 1e9))
                    wait = min(due - now, clock_period)
                else:
                    wait = due - now
                if self._stop.wait(wait):
                    return
            if self.clock_pub is not None:
                self._publish_clock(t_ns)
            self.pubs[topic].publish(data)
            sent += 1
            if time.monotonic() >= next_report:
                next_report += cfg.progress_period_s
                self._report(pass_index, sent, t_ns, t_first)
        if t_first is not None:
            self._report(pass_index, sent, t_ns, t_first, done=True)

    def _publish_clock(self, t_ns: int):
        self.clock_pub.publish(Clock(clock=seconds_to_stamp(t_ns * 1e-9)))

    def _report(self, pass_index, sent, t_ns, t_first, done=False):
        what = 'finished' if done else 'playing'
        self.get_logger().info(
            f'{what} pass {pass_index + 1}: {sent}/{self.total} messages, bag time '
            f'{(t_ns - self.info.start_ns) * 1e-9:.3f}/{self.info.duration_s:.3f} s')

    def _drain(self):
        """Let reliable subscribers receive the last messages before the process ends."""
        for pub in self.pubs.values():
            if pub.get_subscription_count():
                pub.wait_for_all_acked(Duration(seconds=2.0))

    # -- shutdown ----------------------------------------------------------------------
    def on_shutdown(self):
        """Stop the player thread."""
        self._stop.set()
        self._player.join(timeout=5.0)


def main(args=None):
    """Run the node (``ros2 run herd_ros NODE``); exits with its status."""
    exit_process(run_node(Replay, args=args))


if __name__ == '__main__':
    main()
