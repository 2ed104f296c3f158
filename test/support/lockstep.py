"""Lock-step simulated clock for the flight runners under test (fly, chain): the runner's
``sleep(d)`` advances the in-process MAVLink vehicle (lpv_sysid.sim.px4_vehicle.vehicle.SimVehicle)
in steps of ``dt`` on simulated time, so the flights run without wall-clock waits."""

from __future__ import annotations

from typing import Any, Callable, Optional


class LockStep:
    """``clock()`` is the simulated time; ``sleep(d)`` steps the vehicle round(d / dt) times (at
    least once), calling ``hook(self)`` after each step. A flight that has not ended after
    ``max_steps`` steps fails the test (bounded loop)."""

    def __init__(self, veh: Any, dt: float = 0.004, max_steps: int = 400_000) -> None:
        self.veh, self.dt, self.t = veh, dt, 0.0
        self.max_steps = max_steps
        self.steps = 0
        self.hook: Optional[Callable[["LockStep"], None]] = None

    def clock(self) -> float:
        return self.t

    def sleep(self, d: float) -> None:
        for _ in range(max(1, int(round(d / self.dt)))):
            self.t += self.dt
            self.steps += 1
            assert self.steps < self.max_steps, "lock-step flight did not end"
            self.veh.step(self.t)
            if self.hook is not None:
                self.hook(self)
