"""The airborne start check shared by phase 2 and the broken-loop run
(:func:`lpv_sysid.flight.vehicle.wait_airborne`): on a scripted vehicle whose home, mode and
state arrive at known times on a fake clock, it asks HOME_POSITION once a second while home is
missing, measures the height above home (NED: -(z - z_home)), and refuses a disarmed vehicle,
a missing state and a vehicle below ``min_height``, naming the run."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from lpv_sysid.errors import SafetyError
from lpv_sysid.flight.vehicle import wait_airborne


class Vehicle:
    """Mode at t >= 0.1 s, state at t >= 0.2 s, home at ``t_home`` (None: never)."""

    def __init__(self, armed=True, z=-30.0, z_home=-5.0, t_home=2.5, state=True):
        self.t = 0.0
        self.commands: list[tuple[float, tuple]] = []
        self.machine = SimpleNamespace(vehicle_mode=None, armed=armed)
        self.envelope = SimpleNamespace(home_position=None)
        self.link = SimpleNamespace(command_long=lambda *a: self.commands.append((self.t, a)))
        self._z, self._z_home, self._t_home, self._state = z, z_home, t_home, state
        self.state = None

    def clock(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += 0.05  # a coarse fake clock: 20 polls a second

    def poll(self, now: float) -> None:
        if now >= 0.1:
            self.machine.vehicle_mode = "HOLD"
        if self._state and now >= 0.2:
            self.state = SimpleNamespace(pos_ned=np.array([0.0, 0.0, self._z]))
        if self._t_home is not None and now >= self._t_home:
            self.envelope.home_position = np.array([0.0, 0.0, self._z_home])


def run(v: Vehicle, min_height: float = 8.0):
    return wait_airborne(v, v.poll, lambda: v.state, v.clock, v.sleep, "phase 2", min_height)


def test_height_is_measured_above_the_home_that_arrives_after_being_asked_for():
    v = Vehicle(z=-30.0, z_home=-5.0, t_home=2.5)
    state, height = run(v)
    assert height == pytest.approx(25.0)  # -(-30 - (-5))
    assert state is v.state
    # HOME_POSITION (242) asked through MAV_CMD_REQUEST_MESSAGE (512) at t = 0, 1, 2 s only
    asks = [t for t, args in v.commands if args == (512, 242.0)]
    assert len(asks) == 3 and asks[0] == 0.0
    assert np.diff(asks) == pytest.approx([1.0, 1.0], abs=0.06)


def test_without_a_home_the_height_is_above_the_local_origin():
    v = Vehicle(z=-12.0, t_home=None)
    _, height = run(v)
    assert height == pytest.approx(12.0)
    assert v.t == pytest.approx(8.0, abs=0.06)  # waited the whole timeout for a home


@pytest.mark.parametrize(
    "vehicle, words",
    [
        (Vehicle(armed=False), "phase 2 starts in the air: the vehicle is not armed"),
        (Vehicle(state=False), "phase 2: no state telemetry from the vehicle"),
        (Vehicle(z=-10.0, z_home=-5.0), "phase 2 needs >= 8 m above home, vehicle at 5.0 m"),
    ],
)
def test_refusals_name_the_run_and_the_reason(vehicle, words):
    with pytest.raises(SafetyError, match=words):
        run(vehicle)
