"""What every importer produces: one flight in core frames (:class:`FlightRecord`: NED world,
FRD body, SI units, seconds on the log's own clock) and the runs it is split into
(:func:`runs_of`: the offboard segments, or windows the user gives)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError

#: clock of the bag stamps: the log's clock shifted by ``FlightRecord.clock_offset_ns``
CLOCKS = ("utc", "declared", "boot", "recording")


@dataclass(frozen=True)
class StateSeries:
    """``state``: NED position (m), Euler ``[phi, theta, psi]`` (rad), FRD body velocity
    (m/s) and rates (rad/s) at ``t`` (s)."""

    t: np.ndarray
    pos_ned: np.ndarray
    euler: np.ndarray
    v_body: np.ndarray
    omega: np.ndarray


@dataclass(frozen=True)
class Channels:
    """A sampled vector signal: ``t`` (N,) s and ``y`` (N, n)."""

    t: np.ndarray
    y: np.ndarray


@dataclass(frozen=True)
class Event:
    """A status line: time (s), level ``OK``/``WARN``/``ERROR``, text and key values."""

    t: float
    level: str
    message: str
    values: dict = field(default_factory=dict)


@dataclass
class FlightRecord:
    """One imported flight in the package's core quantities.

    ``imu``: FRD specific force (3) and rates (3); ``rotors``: Omega_1..4 (rad/s, PX4
    numbering) with ``rotor_source`` ``esc`` (measured) or ``estimated`` (motor outputs
    through seed 0 Eq. 8); ``reference``: ``[u_d, v_d, w_d, r_d]`` (FRD, heading frame: the
    world velocity setpoint rotated by the vehicle's yaw, as PX4 rotates a ``body_ned``
    setpoint); ``rate_setpoint``: ``[thrust, p_sp, q_sp, r_sp]`` (thrust in [0, 1]).
    ``offboard``: intervals (s) in offboard mode. Bag stamps are
    ``round(t * 1e9 * clock_rate) + clock_offset_ns`` (``clock`` ``utc``: epoch ns from the
    log's GPS time; ``declared``: an epoch the user declared for the boot; ``boot``: no wall clock
    known, time since boot; ``recording``: the clock of a recording of the same flight,
    :func:`px4_clock_of`)."""

    source: str
    state: StateSeries
    imu: Channels | None = None
    rotors: Channels | None = None
    rotor_source: str = "esc"
    reference: Channels | None = None
    rate_setpoint: Channels | None = None
    events: list[Event] = field(default_factory=list)
    offboard: list[tuple[float, float]] = field(default_factory=list)
    provenance: dict[str, Any] = field(default_factory=dict)
    clock_offset_ns: int = 0
    clock: str = "boot"
    clock_rate: float = 1.0  # bag ns per source ns (a PX4 clock fitted against the bags)
    #: (source time s (K,), offset ns (K,)): the offset interpolated in these knots replaces
    #: clock_offset_ns / clock_rate (a PX4 clock measured against a recording's)
    clock_knots: tuple[np.ndarray, np.ndarray] | None = None

    def stamps_ns(self, t: np.ndarray) -> np.ndarray:
        """Bag stamps (int ns) of source times ``t`` (s)."""
        t = np.asarray(t, dtype=float)
        if self.clock_knots is not None:
            kt, ko = self.clock_knots
            return np.round(t * 1e9 + np.interp(t, kt, ko)).astype(np.int64)
        return np.round(t * 1e9 * self.clock_rate).astype(np.int64) + np.int64(
            self.clock_offset_ns
        )

    notes: list[str] = field(default_factory=list)

    @property
    def span(self) -> tuple[float, float]:
        return float(self.state.t[0]), float(self.state.t[-1])


@dataclass(frozen=True)
class Run:
    """One run to write: a name and its interval (s, log clock)."""

    name: str
    start: float
    end: float


def parse_window(text: str, index: int) -> Run:
    """``START:END`` or ``START:END:NAME`` (seconds on the log's clock) -> :class:`Run`."""
    parts = str(text).split(":")
    if len(parts) not in (2, 3):
        raise ConfigError(f"window {text!r}: expected START:END or START:END:NAME (seconds)")
    try:
        a, b = float(parts[0]), float(parts[1])
    except ValueError:
        raise ConfigError(f"window {text!r}: START and END must be numbers (s)") from None
    if not (np.isfinite(a) and np.isfinite(b) and b > a):
        raise ConfigError(f"window {text!r}: need finite START < END")
    name = parts[2] if len(parts) == 3 and parts[2] else f"window_{index}"
    return Run(name, a, b)


def runs_of(
    rec: FlightRecord, windows: Sequence[str] = (), min_duration: float = 1.0
) -> list[Run]:
    """The runs of ``rec``: the ``windows`` given (``START:END[:NAME]``), else its offboard
    segments of at least ``min_duration`` s; ConfigError when there are none or a window
    holds no state sample."""
    if windows:
        runs = [parse_window(w, i) for i, w in enumerate(windows)]
    else:
        runs = [
            Run(f"offboard_{i}", a, b)
            for i, (a, b) in enumerate(rec.offboard)
            if b - a >= min_duration
        ]
        if not runs:
            raise ConfigError(
                f"{rec.source}: no offboard segment of >= {min_duration:g} s "
                f"(segments: {[(round(a, 2), round(b, 2)) for a, b in rec.offboard]}); "
                "give the runs as windows START:END"
            )
    t = rec.state.t
    for r in runs:
        if not np.any((t >= r.start) & (t <= r.end)):
            lo, hi = rec.span
            raise ConfigError(
                f"{rec.source}: run {r.name} [{r.start:g}, {r.end:g}] s holds no state sample "
                f"(the log spans {lo:.3f} .. {hi:.3f} s)"
            )
    return runs


def segments(t: np.ndarray, on: np.ndarray, t_end: float) -> list[tuple[float, float]]:
    """Intervals where the step signal ``on`` (held from each sample to the next) is true;
    the last one ends at ``t_end``."""
    out: list[tuple[float, float]] = []
    start = None
    for ti, flag in zip(np.asarray(t, float), np.asarray(on, bool)):
        if flag and start is None:
            start = float(ti)
        elif not flag and start is not None:
            out.append((start, float(ti)))
            start = None
    if start is not None:
        out.append((start, float(t_end)))
    return out


def interp_rows(tq: np.ndarray, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Linear interpolation of every column of ``y`` (N, n) sampled at ``t`` onto ``tq``
    (held at the ends)."""
    y = np.asarray(y, float)
    if y.ndim == 1:
        return np.interp(tq, t, y)
    return np.column_stack([np.interp(tq, t, y[:, k]) for k in range(y.shape[1])])


def px4_clock_of(experiment: str | Path) -> tuple[int, float, tuple | None]:
    """``(boot_ns, rate, knots)`` of PX4's clock on the bag clock of a ``fly`` recording of
    the same flight (its ``experiment.yaml``: ``vehicle.px4_clock``, measured from the MAVLink
    ``time_boot_ms``; knots ``(t_s, offset_ns)`` arrays or None): a ULog imported with it
    lines up with those bags."""
    from lpv_sysid.io.files import read_yaml

    p = Path(experiment)
    if p.is_dir():
        p = p / "experiment.yaml"
    doc = read_yaml(p)
    clk = ((doc or {}).get("vehicle") or {}).get("px4_clock") or {}
    boot, rate = clk.get("boot_ns"), clk.get("rate", 1.0)
    if not isinstance(boot, int) or not isinstance(rate, (int, float)) or not rate > 0:
        why = f" ({clk['note']})" if clk.get("note") else ": not a fly recording"
        raise ConfigError(f"{p}: no vehicle.px4_clock (boot_ns, rate){why}")
    knots = None
    k = clk.get("knots")
    if isinstance(k, list) and len(k) >= 2:
        arr = np.asarray(k, dtype=float)
        if arr.ndim != 2 or arr.shape[1] != 2 or np.any(np.diff(arr[:, 0]) <= 0):
            raise ConfigError(f"{p}: vehicle.px4_clock.knots: expected increasing [t_s, ns] pairs")
        knots = (arr[:, 0], arr[:, 1])
    return boot, float(rate), knots
