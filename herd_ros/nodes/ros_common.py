"""What every herd_ros node shares: the run loop, time conversion, diagnostics, parameters.

Kept small on purpose — nodes translate messages and parameters and hand the work to the
core modules (which never import rclpy).
"""
from __future__ import annotations

import signal
import sys
import threading

import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.exceptions import ParameterUninitializedException
from rclpy.executors import ExternalShutdownException
from rclpy.parameter import Parameter

OK, WARN, ERROR, STALE = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR,
                          DiagnosticStatus.STALE)


class ParameterError(ValueError):
    """A parameter value a node cannot run with; the message names the parameter."""


def declare_parameters(node, defaults: dict) -> dict:
    """Declare every parameter of ``defaults`` and return {name: value}.

    A default that is a value is declared with dynamic typing (so ``1`` is accepted for
    ``1.0`` and the node validates types itself); a default that is a ``Parameter.Type``
    (e.g. ``STRING_ARRAY``, whose empty default ROS cannot infer) is declared typed and reads
    as ``[]`` when not given. Parameters already declared from overrides keep their value.
    """
    dynamic = ParameterDescriptor(dynamic_typing=True)
    values = {}
    for name, default in defaults.items():
        typed = isinstance(default, Parameter.Type)
        if not node.has_parameter(name):
            if typed:
                node.declare_parameter(name, default)
            else:
                node.declare_parameter(name, default, dynamic)
        try:
            value = node.get_parameter(name).value
        except ParameterUninitializedException:      # typed, no default given
            value = None
        values[name] = ([] if typed else default) if value is None else value
    return values


def stamp_to_seconds(stamp) -> float:
    """builtin_interfaces/Time -> float seconds."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def seconds_to_stamp(t: float) -> Time:
    """float seconds -> builtin_interfaces/Time (nanoseconds rounded, never negative)."""
    ns = max(int(round(t * 1e9)), 0)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def diagnostic_status(name: str, level, message: str, values: dict | None = None,
                      hardware_id: str = '') -> DiagnosticStatus:
    """A DiagnosticStatus with key/values rendered as text."""
    level_byte = bytes([level]) if isinstance(level, int) else level
    return DiagnosticStatus(level=level_byte, name=name, message=message,
                            hardware_id=hardware_id,
                            values=[KeyValue(key=str(k), value=_fmt(v))
                                    for k, v in (values or {}).items()])


def diagnostic_array(node, statuses) -> DiagnosticArray:
    msg = DiagnosticArray()
    msg.header.stamp = node.get_clock().now().to_msg()
    msg.status = list(statuses)
    return msg


def _fmt(v) -> str:
    if isinstance(v, float):
        return f'{v:.6g}'
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
    """Spin one callback at a time until ``stop`` is set or the context is shut down.

    ``executor.spin()`` would not do: the events executor's spin runs in C++ without
    returning to Python (Python signal handlers never run), and a busy classic executor
    starts callbacks back to back. Here the stop flag is checked after every callback and
    at least every :data:`SPIN_WAKE_S`, and the context stays valid until the loop has
    ended, so no callback ever publishes on a shut-down context.
    """
    while not stop.is_set() and context.ok():
        executor.spin_once(timeout_sec=SPIN_WAKE_S)


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
    from rclpy.signals import SignalHandlerOptions
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
        try:
            spin_until_stopped(executor, node.context, stop)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
    finally:
        if node is not None:
            hook = getattr(node, 'on_shutdown', None)
            if hook is not None:
                hook()
            if executor is not None:
                executor.remove_node(node)
            node.destroy_node()
        if executor is not None:
            executor.shutdown()
        context = rclpy.get_default_context()
        rclpy.try_shutdown()
        context.destroy()          # the DDS participant goes now, not at interpreter exit
    return 0


def exit_process(code: int):
    """End a node's process with ``code`` once :func:`run_node` has shut everything down.

    The node, its DDS entities and the context are already destroyed and every file it
    writes is closed; what remains is the interpreter tearing down numpy, scipy, numba and
    pandas module by module, which takes 0.1-0.3 s per process, 0.6-1 s when a whole graph
    stops at once on two cores (measured). So: flush, run the ``atexit`` handlers, and
    leave at once (``os._exit``), keeping a stop within the second ``ros2 launch`` allows.
    """
    import atexit
    import os
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    atexit._run_exitfuncs()
    os._exit(int(code))
