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
