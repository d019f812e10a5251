"""What the multi-process node tests share: a listener node on the test's domain, and
starting/stopping console scripts. (Fixtures that set DDS up are in conftest.py.)"""
import signal
import subprocess
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node


class TestListener:
    """An rclpy context + node of the test on the subprocesses' domain, recording topics."""

    __test__ = False  # not a test class

    def __init__(self, env, name='test_listener'):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=int(env['ROS_DOMAIN_ID']))
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.log = {}

    def record(self, msg_type, topic, stamped=True, depth=100):
        """A list that fills with ``(wall_time, msg)`` (or ``msg`` with ``stamped=False``)."""
        entries = self.log.setdefault(topic, [])
        if stamped:
            callback = lambda m: entries.append((time.time(), m))  # noqa: E731
        else:
            callback = entries.append
        self.node.create_subscription(msg_type, topic, callback, depth)
        return entries

    def spin(self, seconds, until=None):
        """Spin for ``seconds`` or until ``until()`` holds; returns whether it held."""
        end = time.time() + seconds
        while time.time() < end:
            self.executor.spin_once(timeout_sec=0.01)
            if until is not None and until():
                return True
        return until is None

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def start(cmd, env, log_path):
    """Start a console script with its output in ``log_path``."""
    return subprocess.Popen(cmd, env=env, stdout=open(log_path, 'w'), stderr=subprocess.STDOUT)


def stop(proc, timeout=5.0):
    """SIGINT (a node's clean shutdown), then SIGKILL after ``timeout``."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
