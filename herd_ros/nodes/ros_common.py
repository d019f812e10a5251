"""What every herd_ros node shares: the run loop, time conversion, diagnostics, parameters.

Kept small on purpose — nodes translate messages and parameters and hand the work to the
core modules (which never import rclpy).
"""
from __future__ import annotations

import signal
import sys

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


_signalled = False


def _on_signal(signum, frame):
    """Ctrl-C / SIGTERM: shut the context down, which ends the spin at its next wake-up.

    Raising KeyboardInterrupt instead would land at an arbitrary bytecode inside rclpy (in
    the middle of building a Task, of converting a message), which rclpy reports as noise
    at exit; shutting the context down is the clean way out.
    """
    global _signalled
    _signalled = True
    rclpy.try_shutdown()


def run_node(node_factory, args=None, executor=None) -> int:
    """``rclpy.init`` → build the node → spin until Ctrl-C/SIGTERM → clean shutdown.

    A :class:`ParameterError` at start-up is printed as one line and exits with status 2.
    The node's ``on_shutdown()`` (if any) runs before the context is torn down (the
    estimator writes its checkpoint there). A signal that lands inside rclpy's C++ message
    conversion surfaces as a pybind11 ``RuntimeError`` instead of ``KeyboardInterrupt``, and
    one that lands inside the executor's task handler as an ``AttributeError`` on a
    destroyed guard condition; after a signal any such exception is a clean stop.
    """
    rclpy.init(args=args)
    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    node = None
    try:
        try:
            node = node_factory()
        except ParameterError as exc:
            print(f'error: {exc}', file=sys.stderr)
            return 2
        if executor is None:
            rclpy.spin(node)
        else:
            executor.add_node(node)
            executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # a signal shuts the context down under a running spin: rclpy then fails inside
        # its own handler (a pybind11 RuntimeError from message conversion, or an
        # AttributeError on a guard condition already destroyed); after a signal that is
        # a clean stop
        if not _signalled:
            raise
    finally:
        if node is not None:
            hook = getattr(node, 'on_shutdown', None)
            if hook is not None:
                hook()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
