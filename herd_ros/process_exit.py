"""Leaving a process without the interpreter's module-by-module teardown.

Once a process' work is done and its files are closed, Python still tears down numpy,
scipy, numba (LLVM) and pandas module by module: 0.1-0.4 s per process (measured: 0.4 s
after ``herd-ros ingest``), 0.6-1 s when a whole ROS graph stops at once on two cores.
"""
from __future__ import annotations

import sys


def exit_process(code: int):
    """End the process with ``code`` once its work is done (a node after
    :func:`herd_ros.nodes.ros_common.run_node` has shut everything down, a command after
    it returned).

    Every file is closed (a node's DDS entities and context are destroyed); what remains
    is the interpreter's teardown (module docstring). So: flush, run the ``atexit``
    handlers, and leave at once (``os._exit``); for a node this keeps a stop within the
    second ``ros2 launch`` allows.
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


def exit_later_without_gil(seconds: float) -> bool:
    """Arm a POSIX timer that ends the process with status 0 after ``seconds`` — from a
    native thread (``timer_create`` with ``SIGEV_THREAD`` calling libc ``_exit(0)``), so it
    fires even when the main thread is blocked inside a C call that holds the GIL (a DDS
    participant's destruction in rclpy's ``destroy_node`` was seen to hang so, where a
    ``threading.Timer`` never runs). Nothing is flushed when it fires: flush first. Returns
    False where the timer cannot be armed (not Linux/glibc): then there is no backstop."""
    import ctypes

    class Sigevent(ctypes.Structure):          # struct sigevent (64 bytes on Linux)
        _fields_ = [('value', ctypes.c_void_p), ('signo', ctypes.c_int),
                    ('notify', ctypes.c_int), ('function', ctypes.c_void_p),
                    ('attribute', ctypes.c_void_p), ('_pad', ctypes.c_byte * 32)]

    class Timespec(ctypes.Structure):
        _fields_ = [('sec', ctypes.c_long), ('nsec', ctypes.c_long)]

    class Itimerspec(ctypes.Structure):
        _fields_ = [('interval', Timespec), ('value', Timespec)]

    sigev_thread, clock_monotonic = 2, 1
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        event = Sigevent(value=0, signo=0, notify=sigev_thread,
                         function=ctypes.cast(libc._exit, ctypes.c_void_p).value)
        timer = ctypes.c_void_p()
        if libc.timer_create(clock_monotonic, ctypes.byref(event), ctypes.byref(timer)):
            return False
        when = Itimerspec(value=Timespec(int(seconds), int(seconds % 1.0 * 1e9)))
        return libc.timer_settime(timer, 0, ctypes.byref(when), None) == 0
    except (AttributeError, OSError, TypeError, ValueError):
        return False
