"""What every herd_ros node shares: the run loop, time conversion, diagnostics, parameters.

Kept small on purpose — nodes translate messages and parameters and hand the work to the
core modules (which never import rclpy).
"""
from __future__ import annotations

import math
import os
import signal
import sys
import threading
from pathlib import Path

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException
from herd_ros import process_exit
from herd_ros.params import Param, ParameterError, problem  # noqa: F401 (re-exported)

#: the nodes end their process with it (:func:`herd_ros.process_exit.exit_process`)
exit_process = process_exit.exit_process

OK, WARN, ERROR, STALE = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR,
                          DiagnosticStatus.STALE)

#: Queue depth of the subscriptions whose newest sample is all that counts: a robot's
#: odometry (the controller) and its velocity command (fleet_sim). A deeper queue is only
#: latency once a busy node falls behind: at depth 10, a controller working off its
#: backlog on a loaded machine acted on odometry up to 0.2 s old (8 robots at 50 Hz), and
#: eight imitation robots overshot their gathering (relative AMD gap 0.2–2.4 against the
#: offline run, where the node keeping up gives 0.02–0.18). Reliable, keep-last 1.
LATEST_ONLY = 1


READ_ONLY_NOTE = ' (read-only: set at start, e.g. with --params-file)'
LIVE_NOTE = ' (live: ros2 param set applies it at once, after validation)'


def parameter_descriptor(name: str, spec: Param) -> ParameterDescriptor:
    """The ROS descriptor of ``spec``: description, range, allowed values, read-only."""
    d = ParameterDescriptor(name=name, dynamic_typing=True, read_only=not spec.live,
                            description=spec.description + (LIVE_NOTE if spec.live
                                                            else READ_ONLY_NOTE))
    if spec.choices:
        d.additional_constraints = 'one of: ' + ', '.join(str(c) for c in spec.choices)
    if spec.range is not None:
        lo, hi = spec.range
        if isinstance(spec.default, float):
            d.floating_point_range = [FloatingPointRange(from_value=float(lo),
                                                         to_value=float(hi))]
        elif isinstance(spec.default, int) and not isinstance(spec.default, bool):
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
    return d


def declare_parameters(node, specs: dict) -> dict:
    """Declare every parameter of ``specs`` ({name: :class:`Param`}) and return {name: value}.

    Each gets its :func:`parameter_descriptor`. A value from a parameters file of the wrong
    type, outside the range or not one of the choices of its :class:`Param` is a
    :class:`ParameterError` naming the parameter (one line at start).
    Parameters already declared from overrides keep their value and get the descriptor.
    """
    values = {}
    for name, spec in specs.items():
        if not isinstance(spec, Param):
            raise TypeError(f'parameter {name}: declare it with a Param (default, description)')
        descriptor = parameter_descriptor(name, spec)
        try:
            if not node.has_parameter(name):
                node.declare_parameter(name, spec.default, descriptor)
            else:
                node.set_descriptor(name, descriptor)
        except InvalidParameterValueException as exc:
            given = getattr(node, '_parameter_overrides', {}).get(name)
            given = f', got {given.value!r}' if given is not None else ''
            why = (f'must be within [{spec.range[0]:g}, {spec.range[1]:g}]{given}'
                   if spec.range is not None else f': {exc}')
            raise ParameterError(f'{name} {why}') from None
        except InvalidParameterTypeException as exc:
            raise ParameterError(f'parameter {name}: {exc}') from None
        values[name] = node.get_parameter(name).value
        why = problem(spec, values[name])
        if why:
            raise ParameterError(f'{name} {why}')
    specs_of(node).update(specs)
    return values


def specs_of(node) -> dict:
    """{name: :class:`Param`} of every parameter ``node`` declared with
    :func:`declare_parameters` (what :class:`LiveParameters` checks a new value against)."""
    if not hasattr(node, '_herd_param_specs'):
        node._herd_param_specs = {}
    return node._herd_param_specs


def number_problem(value, minimum: float = 0.0, strict: bool = True) -> str | None:
    """Why ``value`` is not a finite number above ``minimum`` (at or above it unless
    ``strict``), or None: the common check of the nodes' live parameters."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return f'must be a number, got {value!r}'
    if value < minimum or (strict and value == minimum):
        return f'must be {">" if strict else ">="} {minimum:g}, got {value}'
    return None


def describe_remaining_parameters(node, descriptions):
    """Give a descriptor to parameters declared without one: ``use_sim_time`` (live) and
    entries of a parameters file taken as overrides (``model.*``, ``flocking.*``; read-only).
    ``descriptions`` is a text, or {name prefix: text} (longest prefix wins, '' = others).
    """
    if isinstance(descriptions, str):
        descriptions = {'': descriptions}
    for name in node.get_parameters_by_prefix(''):
        current = node.describe_parameter(name)
        if current.description:
            continue
        if name == 'use_sim_time':
            text, read_only = ('follow /clock (a replayed bag or a simulator) instead of the '
                               'system clock' + LIVE_NOTE), False
        else:
            prefix = max((p for p in descriptions if name.startswith(p)), key=len, default='')
            text = descriptions.get(prefix, 'not a parameter of this node (ignored)')
            text, read_only = text + READ_ONLY_NOTE, True
        d = ParameterDescriptor(name=name, description=text, read_only=read_only,
                                dynamic_typing=current.dynamic_typing)
        if not current.dynamic_typing:
            d.type = current.type
        node.set_descriptor(name, d)


class LiveParameters:
    """Validate and apply ``ros2 param set`` on the node's live parameters.

    A value must first fit the parameter's table entry (type, range, choices:
    :func:`herd_ros.params.problem`); then ``validate(name, value) -> str | None`` returns
    why it is refused (None = fine), for what the table cannot say;
    ``apply(name, value)`` makes it take effect. Read-only parameters never reach here
    (ROS refuses them by their descriptor); a refused value leaves the parameter unchanged
    and the reason goes back to the caller and into the log.
    """

    def __init__(self, node, validate, apply):
        self.node, self.validate, self.apply = node, validate, apply
        node.add_on_set_parameters_callback(self._on_set)
        node.add_post_set_parameters_callback(self._post_set)

    def _on_set(self, params):
        for p in params:
            if p.name == 'use_sim_time':
                continue
            spec = specs_of(self.node).get(p.name)
            reason = (spec is not None and problem(spec, p.value)) or self.validate(p.name,
                                                                                  p.value)
            if reason:
                self.node.get_logger().warning(f'refused {p.name} = {p.value!r}: {reason}')
                return SetParametersResult(successful=False, reason=f'{p.name}: {reason}')
        return SetParametersResult(successful=True)

    def _post_set(self, params):
        for p in params:
            if p.name == 'use_sim_time':
                continue
            self.apply(p.name, p.value)
            self.node.get_logger().info(f'parameter {p.name} = {p.value!r} applied')


def data_directory() -> Path:
    """Where the nodes write their files unless given an absolute path:
    ``$ROS_HOME/herd_ros`` (``~/.ros/herd_ros`` by default, beside ROS's own ``log``),
    never the shell's working directory."""
    ros_home = os.environ.get('ROS_HOME') or os.path.join(os.path.expanduser('~'), '.ros')
    return Path(ros_home) / 'herd_ros'


def data_path(name: str) -> Path:
    """``name`` as the node will write it: absolute (``~`` expanded) as given, relative
    under :func:`data_directory` (created when needed)."""
    path = Path(os.path.expanduser(str(name)))
    if path.is_absolute():
        return path
    root = data_directory()
    root.mkdir(parents=True, exist_ok=True)
    return root / path


def wall_timer(node, period_s: float, callback):
    """A timer on the steady (wall) clock, whatever ``use_sim_time`` says: diagnostics,
    markers, checkpoints and flushes are for people and disks, not for the data. On the
    node clock they would follow a bag's /clock and fire ``rate`` times as often (30 Hz
    instead of 1 Hz for a replay at rate 30: measured, the estimator's markers alone then
    took 14 s of the demo's 140 s and starved the data path of the one-process graph)."""
    from rclpy.clock import Clock, ClockType
    return node.create_timer(period_s, callback, clock=Clock(clock_type=ClockType.STEADY_TIME))


def pose_array_xy(msg, finite: bool = False) -> np.ndarray:
    """(x, y) of every pose of a geometry_msgs/PoseArray as a (K, 2) array; with ``finite``
    only the poses with finite coordinates (missing agents are NaN)."""
    xy = np.array([(q.position.x, q.position.y) for q in msg.poses], dtype=float).reshape(-1, 2)
    return xy[np.isfinite(xy).all(axis=1)] if finite else xy


def stamp_to_seconds(stamp) -> float:
    """builtin_interfaces/Time -> float seconds."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def seconds_to_stamp(t: float) -> Time:
    """float seconds -> builtin_interfaces/Time (nanoseconds rounded, never negative)."""
    ns = max(int(round(t * 1e9)), 0)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def matrix_message(rows, column_label: str, row_label: str = 'agent'):
    """A Float64MultiArray of a 2-D array (rows × columns, row-major, labelled)."""
    a = np.asarray(rows, dtype=float)
    if a.ndim != 2:
        raise ValueError(f'matrix_message needs a 2-D array, got shape {a.shape}')
    return tensor_message(a, (row_label, column_label))


def tensor_message(values, labels):
    """A Float64MultiArray of an n-D array (row-major), one labelled dimension per axis."""
    import array

    from std_msgs.msg import Float64MultiArray, MultiArrayDimension
    a = np.asarray(values, dtype=float)
    msg = Float64MultiArray()
    strides = np.cumprod(a.shape[::-1])[::-1]
    msg.layout.dim = [MultiArrayDimension(label=label, size=int(size), stride=int(stride))
                      for label, size, stride in zip(labels, a.shape, strides)]
    msg.data = array.array('d', a.ravel())
    return msg


def diagnostic_status(name: str, level, message: str, values: dict | None = None,
                      hardware_id: str = '') -> DiagnosticStatus:
    """A DiagnosticStatus with key/values rendered as text."""
    level_byte = bytes([level]) if isinstance(level, int) else level
    return DiagnosticStatus(level=level_byte, name=name, message=message,
                            hardware_id=hardware_id,
                            values=[KeyValue(key=str(k), value=_fmt(v))
                                    for k, v in (values or {}).items()])


def refresh_status(status: DiagnosticStatus | None, name: str, level, message: str,
                   values: dict, hardware_id: str = '') -> DiagnosticStatus:
    """:func:`diagnostic_status`, reusing ``status`` (and its KeyValue objects) when it has
    the same keys: a node reporting a thousand collars every second builds their statuses
    in a third of the time (constructing a message object checks every field)."""
    if status is None or len(status.values) != len(values) or any(
            kv.key != k for kv, k in zip(status.values, values)):
        return diagnostic_status(name, level, message, values, hardware_id)
    status.level = bytes([level]) if isinstance(level, int) else level
    status.message = message
    for kv, v in zip(status.values, values.values()):
        kv.value = _fmt(v)
    return status


def diagnostic_array(node, statuses) -> DiagnosticArray:
    """A DiagnosticArray of ``statuses`` stamped with ``node``'s clock."""
    msg = DiagnosticArray()
    msg.header.stamp = node.get_clock().now().to_msg()
    msg.status = list(statuses)
    return msg


def _fmt(v) -> str:
    """Diagnostic values as text: six significant digits, but stamps and other large
    numbers in full (``1781530000.125``, not ``1.78153e+09``)."""
    if isinstance(v, float):
        return f'{v:.3f}' if abs(v) >= 1e5 else f'{v:.6g}'
    return str(v)


def make_executor(kind: str, context, logger=None):
    """The executor a node's ``executor`` parameter names: ``events`` =
    ``rclpy.experimental.EventsExecutor`` (about 4x the small-message throughput),
    ``single_threaded`` = ``SingleThreadedExecutor`` (also the fallback when the events
    executor is unavailable)."""
    from rclpy.executors import SingleThreadedExecutor
    if kind == 'events':
        try:
            from rclpy.experimental import EventsExecutor
            return EventsExecutor(context=context)
        except Exception as exc:  # noqa: BLE001 - older rclpy: no experimental executor
            if logger is not None:
                logger.warn(f'EventsExecutor unavailable ({exc}); using SingleThreadedExecutor')
    return SingleThreadedExecutor(context=context)


#: Longest a wait of the run loop blocks (s): a signal is acted on within this much of an
#: idle node, within one callback of a busy one.
SPIN_WAKE_S = 0.1


def spin_until_stopped(executor, context, stop: threading.Event):
    """Spin until ``stop`` is set or the context is shut down.

    ``executor.spin()`` would not do: the events executor's spin runs in C++ without
    returning to Python (Python signal handlers never run), and a busy classic executor
    starts callbacks back to back. Here the classic executor runs one callback at a time
    and the stop flag is checked after each; the events executor runs its callbacks in C++
    for at most :data:`SPIN_WAKE_S` at a time (``spin_until_future_complete`` of a future
    that never completes: a loop of ``spin_once`` cost ``gps_ingest`` 3 % of a core at
    5 000 fixes/s in the loop and its checks), so the flag is checked at least every
    :data:`SPIN_WAKE_S` either way. The context stays valid until the loop has ended, so no
    callback ever publishes on a shut-down context.
    """
    if type(executor).__name__ == 'EventsExecutor':
        from rclpy.task import Future
        never = Future()
        while not stop.is_set() and context.ok():
            executor.spin_until_future_complete(never, timeout_sec=SPIN_WAKE_S)
        return
    while not stop.is_set() and context.ok():
        executor.spin_once(timeout_sec=SPIN_WAKE_S)


def freeze_startup_objects():
    """Keep the objects built at start-up out of the garbage collector's full passes.

    A node holds hundreds of thousands of long-lived objects once built (numpy, pandas,
    numba and llvmlite internals, one publisher and subscription per collar, ...). Python's
    full (generation 2) collection walks all of them: measured on ``gps_ingest`` with 1 000
    collars, 8 full passes in 20 s of 96 ms on average (185 ms at most), each stalling
    every callback, the whole p99 latency of the node. ``gc.freeze()`` moves them to the
    permanent generation (CPython ≥ 3.7, the remedy its documentation gives), so a full
    pass walks only what the node allocates while it runs.
    """
    import gc
    gc.collect()
    gc.freeze()


def run_node(node_factory, args=None) -> int:
    """``rclpy.init`` → build the node → spin until one SIGINT/SIGTERM → save → clean exit.

    One signal is enough, busy or idle (``ros2 launch``, a supervisor or launch_testing
    send exactly one): the handler only sets a flag, the run loop
    (:func:`spin_until_stopped`) sees it after the current callback, then the node's
    ``on_shutdown()`` (if any) saves what it must while the context is still valid (the
    estimator its checkpoint and model, the recorder its footer), and the node and context
    are torn down. Exit status 0; a :class:`ParameterError` at start-up is printed as one
    line and exits with status 2. A second signal during the teardown is ignored.

    The node chooses its executor with an ``executor_kind`` attribute (``events`` or
    ``single_threaded``, the default); a node may end the run itself by shutting its
    context down (replay at the end of the bag).
    """
    import faulthandler
    from rclpy.signals import SignalHandlerOptions
    # `kill -USR1 <pid>` prints every thread's stack to stderr: what a hung node is doing
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    node = executor = None
    try:
        try:
            node = node_factory()
        except ParameterError as exc:
            print(f'error: {exc}', file=sys.stderr)
            return 2
        executor = make_executor(getattr(node, 'executor_kind', 'single_threaded'),
                                 node.context, node.get_logger())
        executor.add_node(node)
        freeze_startup_objects()
        try:
            spin_until_stopped(executor, node.context, stop)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
    finally:
        if node is not None:
            hook = getattr(node, 'on_shutdown', None)
            if hook is not None:
                hook()
        if stop.is_set():
            _teardown_watchdog()
        if node is not None:
            if executor is not None:
                executor.remove_node(node)
            node.destroy_node()
        if executor is not None:
            executor.shutdown()
        context = rclpy.get_default_context()
        rclpy.try_shutdown()
        context.destroy()          # the DDS participant goes now, not at interpreter exit
    return 0


#: Longest the DDS teardown may take after a stop signal once the node's files are saved (s).
TEARDOWN_LIMIT_S = 0.5
#: the native backstop fires this long after the Python watchdog would have
NATIVE_MARGIN_S = 0.2


def _teardown_watchdog():
    """After a stop signal, once ``on_shutdown`` has saved what it must: if destroying the
    node, executor and DDS participant has not finished within :data:`TEARDOWN_LIMIT_S`,
    leave anyway with status 0 (one line on stderr, no traceback). A launch or supervisor
    waits for the process, not for its participant; once in some thirty whole-graph stops a
    node was seen still alive 10 s after its signal, somewhere in that teardown: blocked in
    rclpy's ``destroy_node`` holding the GIL, where this Python timer cannot run — so a
    native timer (:func:`herd_ros.process_exit.exit_later_without_gil`) ends the process
    with status 0 :data:`NATIVE_MARGIN_S` later whatever the interpreter is doing (the
    whole stop stays within the second ``ros2 launch`` allows)."""
    import os

    def expire():
        print(f'teardown took longer than {TEARDOWN_LIMIT_S:g} s after the stop signal: '
              f'exiting without it', file=sys.stderr)
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(0)

    timer = threading.Timer(TEARDOWN_LIMIT_S, expire)
    timer.daemon = True
    timer.start()
    for stream in (sys.stdout, sys.stderr):     # the native timer flushes nothing
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    process_exit.exit_later_without_gil(TEARDOWN_LIMIT_S + NATIVE_MARGIN_S)


