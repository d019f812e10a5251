"""The fleet_sim core without ROS (issue 26): watchdog, fence wall, collision counts and the
grid of published states, against hand-computed cases."""
import numpy as np
import pytest

from herd_ros.params import ParameterError
from herd_ros.params.fleet_sim import PARAMS, FleetSimConfig
from herd_ros.simulation.fleet import FleetSimulator


def config(**given):
    values = {name: spec.default for name, spec in PARAMS.items()}
    values.update(robots=['r1', 'r2'], max_accel=1e6, rate_hz=10.0, cmd_timeout_s=1.05)
    values.update(given)
    return FleetSimConfig(values)


def test_a_command_drives_until_the_watchdog_stops_the_robot():
    fleet = FleetSimulator(config())
    start = fleet.state.positions.copy()           # robots 2 m apart on the x axis
    fleet.integrate_to(1.0)                        # grid starts at 1.0
    fleet.set_command(0, 1.0, (0.5, 0.0, 0.0))     # 0.5 m/s east, body = world (yaw 0)
    fleet.integrate_to(1.8)
    assert fleet.state.positions[0, 0] - start[0, 0] == pytest.approx(0.4, abs=1e-9)
    assert np.allclose(fleet.state.positions[1], start[1])   # never commanded: stays
    fleet.integrate_to(3.0)        # stale after 1.05 s: the span ending at 2.1 is cut (the
    # watchdog judges each step at its end), so it stopped at 2.0
    assert fleet.state.positions[0, 0] - start[0, 0] == pytest.approx(0.5, abs=1e-9)
    assert fleet.stale(3.0).tolist() == [True, True] and fleet.stale_events[0] == 1
    times = [t for t, _, _ in fleet.take_snapshots()]
    assert times == pytest.approx(np.arange(1.0, 3.0 + 1e-9, 0.1))   # every step period


def test_the_fence_is_a_wall_and_overlaps_are_counted():
    fleet = FleetSimulator(config(fence=[-1.0, -1.0, 2.5, -1.0, 2.5, 1.0, -1.0, 1.0],
                                  robot_radius=0.3, max_speed=3.0))
    fleet.integrate_to(1.0)
    fleet.set_command(1, 1.0, (1.0, 0.0, 0.0))     # robot 2 at x = 2 heads for x = 2.5
    fleet.integrate_to(1.9)
    assert fleet.state.positions[1, 0] <= 2.5 and fleet.fence_contacts[1] >= 1
    fleet.set_command(0, 1.9, (2.0, 0.0, 0.0))     # robot 1 at x = 0 runs into robot 2
    fleet.set_command(1, 1.9, (0.0, 0.0, 0.0))
    fleet.integrate_to(2.9)                        # x = 2.0, robot 2 at 2.4-2.5: overlap
    assert fleet.collisions[0] == 1 and fleet.overlap[0]


def test_a_clock_jump_restarts_the_grid():
    fleet = FleetSimulator(config())
    fleet.integrate_to(1.0)
    fleet.integrate_to(1000.0)                     # > 100 periods: not stepped through
    assert len(fleet.take_snapshots()) == 2 and 'clock jumped' in fleet.log[0]


def test_config_refuses_what_the_table_cannot_say():
    with pytest.raises(ParameterError, match='initial_poses'):
        config(initial_poses=[0.0, 0.0])
    with pytest.raises(ParameterError, match='inside the fence'):
        config(fence=[10.0, 10.0, 20.0, 10.0, 20.0, 20.0])
