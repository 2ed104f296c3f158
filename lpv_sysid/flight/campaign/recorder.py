"""Recording of `lpv-sysid fly phase1`: one rosbag2 per run and the whole flight
(:class:`CampaignRecorder`), with the data logger's topics."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Mapping

from lpv_sysid.errors import LpvSysidError
from lpv_sysid.io.messages import TOPIC_NAMESPACE as NAMESPACE

TOPICS = (
    "state",
    "rotor_speeds",
    "imu",
    "velocity_reference",
    "excitation",
    "actuator_command",
    "status",
)
#: with ``record_rate_setpoints``: PX4's ATTITUDE_TARGET (thrust + body-rate setpoints of its own
#: cascade) as a JointState (names ``transport.RATE_INPUT_NAMES``, ``position``), receive-time
#: stamps
RATE_TOPIC = "rate_setpoint"


class CampaignRecorder:
    """One rosbag2 per run (the runs recorder, split at each run) + the whole flight."""

    def __init__(
        self,
        out_dir: Path,
        storage: str,
        flight_log: bool,
        config_files=(),
        description="",
        rate_setpoints: bool = False,
        clock_offset_ns: int = 0,
    ) -> None:
        """``clock_offset_ns``: added to the flight clock's ``round(t * 1e9)`` for every
        stamp, so that the bags carry wall-clock (epoch) stamps when the flight's clock is
        ``time.monotonic`` (``fly`` passes ``time.time_ns() - monotonic_ns`` at start, or a
        declared epoch)."""
        from lpv_sysid.io import messages
        from lpv_sysid.io.recorder import Recorder, RecorderConfig

        self.messages = messages
        self.f = messages.MsgFactory.rosbags()
        topics = {f"{NAMESPACE}/{n}": messages.TYPES[n] for n in TOPICS}
        if rate_setpoints:
            topics[f"{NAMESPACE}/{RATE_TOPIC}"] = messages.TYPES["actuator_command"]  # JointState
        self.runs = Recorder(
            RecorderConfig(
                out_dir=str(out_dir),
                topics=topics,
                storage=storage,
                config_files=tuple(config_files),
                description=description,
            )
        )
        self.flight = (
            Recorder(
                RecorderConfig(
                    out_dir=str(out_dir / "flight"),
                    topics=topics,
                    storage=storage,
                    description="whole flight (not a maneuver)",
                )
            )
            if flight_log
            else None
        )
        self.clock_offset_ns = int(clock_offset_ns)
        #: PX4 time (s since boot) -> bag ns, when known (``fly``: the vehicle record's live
        #: estimate); then telemetry is stamped at the time PX4 sampled it, not received it
        self.vehicle_clock: Callable[[float], int | None] | None = None
        self.active: str | None = None  # run being recorded
        self.bags: dict[str, str] = {}  # run name -> bag directory name
        self.started = False
        self.error: str | None = None

    def _ns(self, t: float) -> int:
        return _ns(t) + self.clock_offset_ns

    def start(self, now: float) -> None:
        self.runs.start(self._ns(now))
        if self.flight is not None:
            self.flight.start(self._ns(now))
        self.started = True

    def annotate(self, key: str, value) -> None:
        """``key: value`` in ``experiment.yaml`` of the runs and of the whole flight."""
        for rec in (self.runs, self.flight):
            if rec is not None:
                rec.annotate(key, value)

    def begin_run(self, name: str) -> str:
        bag = self.runs.split()
        self.active = name
        self.bags[name] = bag
        return bag

    def end_run(self) -> None:
        self.active = None

    def _write(self, topic: str, stamp: int, msg) -> None:
        if self.error is not None:
            return
        try:
            if self.active is not None:
                self.runs.record(f"{NAMESPACE}/{topic}", stamp, msg)
            if self.flight is not None:
                self.flight.record(f"{NAMESPACE}/{topic}", stamp, msg)
        except LpvSysidError as exc:
            self.error = str(exc)
            raise

    def message(self, topic: str, t: float, msg) -> None:
        """A message as published (``topic`` of :data:`TOPICS` or :data:`RATE_TOPIC`), logged
        at ``t`` [s] (its send or receipt time; the header keeps its own stamp)."""
        self._write(topic, self._ns(t), msg)

    def _sample_ns(self, t: float, t_vehicle: float | None) -> int:
        if t_vehicle is not None and self.vehicle_clock is not None:
            ns = self.vehicle_clock(t_vehicle)
            if ns is not None:
                return ns
        return self._ns(t)

    def state(self, t: float, pos_ned, euler, v_body, omega, t_vehicle=None) -> None:
        st = self._sample_ns(t, t_vehicle)
        self._write(
            "state",
            st,
            self.messages.odometry_from_state(self.f, st, pos_ned, euler, v_body, omega),
        )

    def imu(self, t: float, accel_frd, gyro_frd, t_vehicle=None) -> None:
        st = self._sample_ns(t, t_vehicle)
        self._write("imu", st, self.messages.imu_msg(self.f, st, accel_frd, gyro_frd))

    def rotors(self, t: float, omega, source: str = "esc", t_vehicle=None) -> None:
        st = self._sample_ns(t, t_vehicle)
        self._write("rotor_speeds", st, self.messages.rotor_speeds_msg(self.f, st, omega, source))

    def rate_setpoint(self, t: float, u) -> None:
        """(thrust, p_sp, q_sp, r_sp) on ``rate_setpoint`` (PX4's ATTITUDE_TARGET or our
        command)."""
        from lpv_sysid.mavlink.bridge import RATE_INPUT_NAMES

        st = self._ns(t)
        self._write(
            RATE_TOPIC, st, self.messages.joint_state(self.f, st, RATE_INPUT_NAMES, position=u)
        )

    def reference(self, t: float, v, r: float) -> None:
        st = self._ns(t)
        self._write("velocity_reference", st, self.messages.twist_reference_msg(self.f, st, v, r))
        self._write(
            "excitation", st, self.messages.excitation_msg(self.f, st, (0.0, 0.0, 0.0, 0.0))
        )

    def status(self, t: float, level: str, message: str, values: Mapping[str, Any]) -> None:
        st = self._ns(t)
        lv = {"info": "OK", "warn": "WARN", "error": "ERROR"}.get(level, level)
        msg = self.messages.diagnostic_array(
            self.f,
            st,
            [self.messages.diagnostic_status(self.f, lv, "lpv_sysid/fly", message, values)],
        )
        self._write("status", st, msg)

    def close(self, now: float) -> list[str]:
        errors = []
        for rec in (self.runs, self.flight):
            if rec is None:
                continue
            try:
                rec.stop(self._ns(now))
            except LpvSysidError as exc:
                errors.append(str(exc))
        return errors


def _ns(t: float) -> int:
    return int(round(float(t) * 1e9))
