"""The controller's start gate (:class:`herd_ros.control.fleet_start.StartGate`): the fleet
is driven once every owned robot has reported, or ``wait_s`` after the first did."""
import numpy as np

from herd_ros.control.fleet_start import StartGate

NEVER = np.nan


def test_closed_until_every_owned_robot_has_reported():
    gate = StartGate(wait_s=5.0)
    owned = np.array([True, True, True, False])       # the fourth is only watched
    assert not gate.update([NEVER] * 4, owned, now=10.0)
    assert not gate.update([10.5, NEVER, NEVER, NEVER], owned, now=11.0)
    assert not gate.update([10.5, 11.2, NEVER, NEVER], owned, now=14.0)
    assert gate.update([10.5, 11.2, 14.9, NEVER], owned, now=15.0)   # the watched one: no matter
    assert gate.missing_at_start == []
    assert gate.update([NEVER] * 4, owned, now=99.0), 'once open it stays open'


def test_opens_wait_s_after_the_first_report_without_the_missing_robot():
    gate = StartGate(wait_s=5.0)
    owned = np.ones(3, bool)
    heard = [NEVER, 20.0, NEVER]
    assert not gate.update(heard, owned, now=20.0)    # the clock of the wait starts here
    assert not gate.update(heard, owned, now=24.9)
    assert gate.update(heard, owned, now=25.0)
    assert gate.missing_at_start == [0, 2]


def test_a_zero_wait_starts_with_the_first_robot_heard():
    gate = StartGate(wait_s=0.0)
    assert not gate.update([NEVER, NEVER], np.ones(2, bool), now=1.0)
    assert gate.update([NEVER, 1.5], np.ones(2, bool), now=1.5)
    assert gate.missing_at_start == [0]
