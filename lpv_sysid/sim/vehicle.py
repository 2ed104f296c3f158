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

from lpv_sysid.configuration import fields as cf
from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.models.quadrotor import Quadrotor

_TWO_PI = 2.0 * math.pi

#: Highest physics rate (RK4 steps per simulated second) accepted; 100x the default.
MAX_PHYSICS_HZ = 50_000.0


def _rate(default: float, doc: str) -> Any:
    return cf.number(default, doc, lo=0.0, lo_open=True, hi=MAX_PHYSICS_HZ, unit=" Hz")


def _std(default: float, doc: str) -> Any:
    return cf.number(default, doc, lo=0.0)


@dataclass(frozen=True)
class SensorConfig:
    """Rates, noise and vibration of the simulated sensors (``config/quadrotor.yaml``
    section ``sim``), checked on every construction."""

    physics_hz: float = _rate(
        500.0, f"RK4 steps per simulated second; at most {MAX_PHYSICS_HZ:g} Hz (100x default)"
    )
    state_hz: float = _rate(250.0, "estimator output rate [Hz], divides physics_hz")
    imu_hz: float = _rate(250.0, "IMU rate [Hz], divides physics_hz")
    rotor_hz: float = _rate(100.0, "ESC telemetry rate [Hz], divides physics_hz")
    pos_std: float = _std(0.02, "position noise [m]")
    att_std_deg: float = _std(0.15, "attitude noise [deg]")
    vel_std: float = _std(0.03, "velocity noise [m/s]")
    rate_std: float = _std(0.008, "body-rate noise of the estimator [rad/s]")
    accel_std: float = _std(0.08, "accelerometer noise [m/s^2]")
    gyro_std: float = _std(0.006, "gyro noise [rad/s]")
    rotor_std: float = _std(2.0, "rotor-speed noise [rad/s]")
    vib_accel: float = _std(2.0, "once-per-rev accelerometer vibration at omega_ref [m/s^2]")
    vib_accel_blade: float = _std(1.0, "blade-pass (2/rev) vibration at omega_ref [m/s^2]")
    vib_gyro: float = _std(0.03, "gyro vibration at omega_ref [rad/s]")
    vib_state_fraction: float = _std(0.1, "share of the gyro vibration in the estimated rates")
    omega_ref: float = cf.number(
        600.0, "rotor speed of the vibration amplitudes [rad/s]", lo=0.0, lo_open=True
    )
    seed: int = cf.count(0, "noise seed")

    def __post_init__(self) -> None:
        """The declared fields, then: every sensor rate divides the physics rate."""
        cf.normalize_fields(self, "sim")
        for name in ("state_hz", "imu_hz", "rotor_hz"):
            ratio = self.physics_hz / getattr(self, name)
            if abs(ratio - round(ratio)) > 1e-9 or ratio < 1:
                raise cf.error("sim", name, f"must divide physics_hz={self.physics_hz}")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "sim") -> "SensorConfig":
        return cls(**cf.parse_fields(cls, d, where))

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
            raise ConfigError(
                f"SimVehicle: initial state must be 16 finite values, got {x0.shape}"
            )
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
        self._pool: list = []  # normals drawn ahead from self.rng (_normals)
        self._pool_i = 0
        self._vib_x = None  # the state _vib_out belongs to
        self._vib_out: tuple[list[float], list[float]] | None = None

    # ------------------------------------------------------------------ physics
    def step(self, u) -> None:
        """Advance one physics step with the virtual command u held constant (RK4,
        :meth:`lpv_sysid.models.quadrotor.Quadrotor.rk4_step`)."""
        h = self.dt
        x = self.x
        u = [float(v) for v in u]
        self.u = u
        xn = self.model.rk4_step(x, u, h)
        lo, hi = self._lo, self._hi
        # rotor speeds clamped to the motor range (RK4 may step a hair past a held limit) and
        # the blade phases integrated (trapezoid), unrolled: 4 rotors, plain floats
        o1, o2, o3, o4 = xn[12:16]
        o1 = xn[12] = lo if o1 < lo else (hi if o1 > hi else o1)
        o2 = xn[13] = lo if o2 < lo else (hi if o2 > hi else o2)
        o3 = xn[14] = lo if o3 < lo else (hi if o3 > hi else o3)
        o4 = xn[15] = lo if o4 < lo else (hi if o4 > hi else o4)
        hh = h * 0.5
        ph = self.rotor_phase
        ph[0] = (ph[0] + hh * (x[12] + o1)) % _TWO_PI
        ph[1] = (ph[1] + hh * (x[13] + o2)) % _TWO_PI
        ph[2] = (ph[2] + hh * (x[14] + o3)) % _TWO_PI
        ph[3] = (ph[3] + hh * (x[15] + o4)) % _TWO_PI
        if not math.isfinite(sum(xn)) and not all(math.isfinite(v) for v in xn):
            raise SafetyError(f"SimVehicle: state diverged at t={self.t:.3f} s (command {u})")
        self.x = xn
        self.t += h

    # ------------------------------------------------------------------ sensors
    def _normals(self, n: int) -> list:
        """The next ``n`` standard normals of ``self.rng``, drawn in blocks: numpy's
        generator yields the same sequence whatever the block sizes, so this is the stream
        ``self.rng.standard_normal(n)`` calls would give, at a fraction of the per-call cost."""
        pool, i = self._pool, self._pool_i
        if i + n > len(pool):
            pool = self._pool = pool[i:] + self.rng.standard_normal(max(4096, n)).tolist()
            i = 0
        self._pool_i = i + n
        return pool[i : i + n]

    def _vibration(self):
        """(accelerometer, gyro) vibration of the current state; computed once per state."""
        if self._vib_x is self.x:
            return self._vib_out
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
        self._vib_x, self._vib_out = self.x, (acc, gyr)
        return acc, gyr

    def measure_state(self) -> np.ndarray:
        """Estimator output as a 16-vector (FULL_STATE_NAMES, rotor entries = truth)."""
        c = self.cfg
        n = self._normals(12)
        x = self.x
        _, gyr = self._vibration()
        sp, sa, sv, sr, fv = (
            c.pos_std,
            math.radians(c.att_std_deg),
            c.vel_std,
            c.rate_std,
            c.vib_state_fraction,
        )
        return np.array(
            [
                x[0] + sp * n[0],
                x[1] + sp * n[1],
                x[2] + sp * n[2],
                x[3] + sa * n[3],
                x[4] + sa * n[4],
                x[5] + sa * n[5],
                x[6] + sv * n[6],
                x[7] + sv * n[7],
                x[8] + sv * n[8],
                x[9] + (sr * n[9] + fv * gyr[0]),
                x[10] + (sr * n[10] + fv * gyr[1]),
                x[11] + (sr * n[11] + fv * gyr[2]),
                x[12],
                x[13],
                x[14],
                x[15],
            ]
        )

    def measure_imu(self):
        """(specific force FRD m/s^2, gyro FRD rad/s) with vibration and noise."""
        c = self.cfg
        x = self.x
        m = self.model
        F, _ = m._fm(
            x[6],
            x[7],
            x[8],
            x[9],
            x[10],
            x[11],
            x[12],
            x[13],
            x[14],
            x[15],
            *m._rotor_rates(x[12:16], [float(v) for v in self.u]),
        )
        mass = m.params.mass
        acc, gyr = self._vibration()
        n = self._normals(6)
        sa, sg = c.accel_std, c.gyro_std
        a = np.array(
            [
                (F[0] / mass + acc[0]) + sa * n[0],
                (F[1] / mass + acc[1]) + sa * n[1],
                (F[2] / mass + acc[2]) + sa * n[2],
            ]
        )
        w = np.array(
            [
                (x[9] + gyr[0]) + sg * n[3],
                (x[10] + gyr[1]) + sg * n[4],
                (x[11] + gyr[2]) + sg * n[5],
            ]
        )
        return a, w

    def measure_rotors(self) -> np.ndarray:
        x, n, s = self.x, self._normals(4), self.cfg.rotor_std
        return np.array([x[12] + s * n[0], x[13] + s * n[1], x[14] + s * n[2], x[15] + s * n[3]])
