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
