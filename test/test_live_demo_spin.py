"""The live demo's spin thread at the end of a run (``live_demo._spin``): a handle destroyed
under a spin that has not returned yet (a saturated machine, the join timed out) ends the
run quietly once the demo is stopping, and is an error before."""
import threading

import pytest

from herd_ros.cli.live_demo import _spin


class RaisingSpin:
    """An executor whose spin fails as rclpy's does when a node is destroyed under it."""

    def spin(self):
        raise RuntimeError('cannot use Destroyable because destruction was requested')


def test_a_failure_while_stopping_ends_the_spin_quietly():
    stopping = threading.Event()
    stopping.set()
    _spin(RaisingSpin(), stopping)


def test_a_failure_before_stopping_is_raised():
    with pytest.raises(RuntimeError, match='Destroyable'):
        _spin(RaisingSpin(), threading.Event())
    with pytest.raises(RuntimeError, match='Destroyable'):
        _spin(RaisingSpin())


def test_the_shutdown_hooks_run_after_the_spin_has_left_every_callback():
    """``stop_graph`` with a real executor and node: a slow timer callback is running when
    the run ends; the node's ``on_shutdown`` must not start before it has returned."""
    import time

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from herd_ros.cli.live_demo import stop_graph

    class Slow(Node):
        def __init__(self, **kw):
            super().__init__('slow_callback_node', **kw)
            self.inside, self.entered, self.overlaps, self.hooked = False, threading.Event(), 0, 0
            self.create_timer(0.01, self.work)

        def work(self):
            self.inside = True
            self.entered.set()
            time.sleep(0.3)
            self.inside = False

        def on_shutdown(self):
            self.hooked += 1
            self.overlaps += self.inside

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = Slow(context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        stopping = threading.Event()
        spinner = threading.Thread(target=_spin, args=(executor, stopping), daemon=True)
        spinner.start()
        assert node.entered.wait(10.0)
        stop_graph(executor, spinner, [node], stopping)
        assert not spinner.is_alive()
        assert node.hooked == 1 and node.overlaps == 0
    finally:
        rclpy.try_shutdown(context=context)
