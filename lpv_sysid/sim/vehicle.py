"""Simulated vehicle: fixed-step RK4 around the seed 0 quadrotor, sensors and vibration.

- Physics: classical RK4 at ``physics_hz`` (default 500 Hz) on the 16-state model of
  ``lpv_sysid.models.quadrotor`` (seed 0 Eqs. 3, 6-8), zero-order hold on the command,
  rotor speeds clamped to [omega_min, omega_max] after every step.
- Sensors, each sampled at its own rate (must divide ``physics_hz``):
  ``state`` (estimator output: NED position, Euler angles, body velocity, body rates;
  default 250 Hz), ``imu`` (specific force and gyro, 250 Hz), ``rotors`` (ESC telemetry
  rotor speeds, 100 Hz).
- Noise: white Gaussian per channel (seeded ``numpy.random.Generator``).
- Vibration: each rotor i with phase phi_i = int Omega_i dt adds an acceleration
  ``(Omega_i / Omega_ref)^2 [A_1 d_i sin(phi_i + a_i) + A_2 e_i sin(2 phi_i + b_i)]`` on the
  accelerometer (once-per-revolution imbalance and blade-pass harmonic, fixed random
  directions d_i, e_i and phases), a proportional angular-rate vibration on the gyro, and
  a fraction ``vib_state_fraction`` of the gyro vibration leaks into the estimator's body
  rates. The harmonics (~100 Hz and ~200 Hz at hover) alias at 250 Hz sampling, as on a
  real multirotor log.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Mapping

import numpy as np

from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.models.quadrotor import Quadrotor
from lpv_sysid.validation import check_keys, is_count, is_finite_number


#: Highest physics rate (RK4 steps per simulated second) accepted; 100x the default.
MAX_PHYSICS_HZ = 50_000.0


@dataclass(frozen=True)
class SensorConfig:
    physics_hz: float = 500.0
    state_hz: float = 250.0
    imu_hz: float = 250.0
    rotor_hz: float = 100.0
    pos_std: float = 0.02            # m
    att_std_deg: float = 0.15        # deg
    vel_std: float = 0.03            # m/s
    rate_std: float = 0.008          # rad/s
    accel_std: float = 0.08          # m/s^2
    gyro_std: float = 0.006          # rad/s
    rotor_std: float = 2.0           # rad/s
    vib_accel: float = 2.0           # m/s^2, once-per-rev amplitude at omega_ref
    vib_accel_blade: float = 1.0     # m/s^2, blade-pass (2/rev) amplitude at omega_ref
    vib_gyro: float = 0.03           # rad/s at omega_ref
    vib_state_fraction: float = 0.1  # share of the gyro vibration in the estimated rates
    omega_ref: float = 600.0         # rad/s
    seed: int = 0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "seed":
                if not is_count(v):
                    raise ConfigError(f"sim.seed: must be a non-negative integer, got {v!r}")
                continue
            if not is_finite_number(v) or v < 0:
                raise ConfigError(f"sim.{f.name}: must be a finite number >= 0, got {v!r}")
        for name in ("physics_hz", "state_hz", "imu_hz", "rotor_hz", "omega_ref"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"sim.{name}: must be > 0")
        if self.physics_hz > MAX_PHYSICS_HZ:    # every simulated second costs physics_hz RK4 steps
            raise ConfigError(f"sim.physics_hz: {self.physics_hz:g} Hz exceeds the limit of {MAX_PHYSICS_HZ:g} Hz")
        for name in ("state_hz", "imu_hz", "rotor_hz"):
            ratio = self.physics_hz / getattr(self, name)
            if abs(ratio - round(ratio)) > 1e-9 or ratio < 1:
                raise ConfigError(f"sim.{name}: must divide physics_hz={self.physics_hz}")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "SensorConfig":
        check_keys(d, {f.name for f in fields(cls)}, "sim")
        return cls(**{k: (float(v) if k != "seed" and isinstance(v, int) and not isinstance(v, bool) else v)
                      for k, v in d.items()})

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def decimation(self, rate_hz: float) -> int:
        return int(round(self.physics_hz / rate_hz))


class SimVehicle:
    """Fixed-step simulated quadrotor with noisy, vibrating sensors."""

    def __init__(self, model: Quadrotor, sensors: SensorConfig | None = None, x0=None) -> None:
        self.model = model
        self.cfg = sensors if sensors is not None else SensorConfig()
        self.dt = 1.0 / self.cfg.physics_hz
        x0 = np.zeros(16) if x0 is None else np.asarray(x0, dtype=float)
        if x0.shape != (16,) or not np.all(np.isfinite(x0)):
            raise ConfigError(f"SimVehicle: initial state must be 16 finite values, got {x0.shape}")
        self.x = x0.tolist()
        self.t = 0.0
        self.rng = np.random.default_rng(self.cfg.seed)
        self.rotor_phase = self.rng.uniform(0, 2 * np.pi, 4).tolist()
        dirs = self.rng.normal(size=(4, 3)) * np.array([0.7, 0.7, 1.0])
        self._vib_dir1 = (dirs / np.linalg.norm(dirs, axis=1, keepdims=True)).tolist()
        dirs = self.rng.normal(size=(4, 3)) * np.array([0.7, 0.7, 1.0])
        self._vib_dir2 = (dirs / np.linalg.norm(dirs, axis=1, keepdims=True)).tolist()
        gd = self.rng.normal(size=(4, 3))
        self._vib_gdir = (gd / np.linalg.norm(gd, axis=1, keepdims=True)).tolist()
        self._vib_ph = self.rng.uniform(0, 2 * np.pi, (4, 2)).tolist()
        self.u = [0.0, 0.0, 0.0, 0.0]
        self._lo, self._hi = model.params.omega_min, model.params.omega_max

    # ------------------------------------------------------------------ physics
    def step(self, u) -> None:
        """Advance one physics step with the virtual command u held constant (RK4)."""
        f = self.model.derivatives_list
        h = self.dt
        x = self.x
        u = [float(v) for v in u]
        self.u = u
        k1 = f(x, u)
        k2 = f([a + 0.5 * h * b for a, b in zip(x, k1)], u)
        k3 = f([a + 0.5 * h * b for a, b in zip(x, k2)], u)
        k4 = f([a + h * b for a, b in zip(x, k3)], u)
        h6 = h / 6.0
        xn = [a + h6 * (b + 2.0 * c + 2.0 * d + e) for a, b, c, d, e in zip(x, k1, k2, k3, k4)]
        lo, hi = self._lo, self._hi
        for i in range(12, 16):
            xn[i] = lo if xn[i] < lo else (hi if xn[i] > hi else xn[i])
            self.rotor_phase[i - 12] = (self.rotor_phase[i - 12] + h * 0.5 * (x[i] + xn[i])) % (2 * math.pi)
        if not all(math.isfinite(v) for v in xn):
            raise SafetyError(f"SimVehicle: state diverged at t={self.t:.3f} s (command {u})")
        self.x = xn
        self.t += h

    # ------------------------------------------------------------------ sensors
    def _vibration(self):
        c = self.cfg
        acc = [0.0, 0.0, 0.0]
        gyr = [0.0, 0.0, 0.0]
        for i in range(4):
            s = (self.x[12 + i] / c.omega_ref) ** 2
            ph = self.rotor_phase[i]
            s1 = s * math.sin(ph + self._vib_ph[i][0])
            s2 = s * math.sin(2.0 * ph + self._vib_ph[i][1])
            d1, d2, gd = self._vib_dir1[i], self._vib_dir2[i], self._vib_gdir[i]
            for k in range(3):
                acc[k] += c.vib_accel * d1[k] * s1 + c.vib_accel_blade * d2[k] * s2
                gyr[k] += c.vib_gyro * gd[k] * s1
        return acc, gyr

    def measure_state(self) -> np.ndarray:
        """Estimator output as a 16-vector (FULL_STATE_NAMES, rotor entries = truth)."""
        c = self.cfg
        n = self.rng.standard_normal(12)
        x = np.array(self.x)
        _, gyr = self._vibration()
        x[0:3] += c.pos_std * n[0:3]
        x[3:6] += math.radians(c.att_std_deg) * n[3:6]
        x[6:9] += c.vel_std * n[6:9]
        x[9:12] += c.rate_std * n[9:12] + c.vib_state_fraction * np.array(gyr)
        return x

    def measure_imu(self):
        """(specific force FRD m/s^2, gyro FRD rad/s) with vibration and noise."""
        c = self.cfg
        sf = self.model.specific_force(np.array(self.x), self.u)
        acc, gyr = self._vibration()
        n = self.rng.standard_normal(6)
        a = sf + np.array(acc) + c.accel_std * n[0:3]
        w = np.array(self.x[9:12]) + np.array(gyr) + c.gyro_std * n[3:6]
        return a, w

    def measure_rotors(self) -> np.ndarray:
        return np.array(self.x[12:16]) + self.cfg.rotor_std * self.rng.standard_normal(4)
