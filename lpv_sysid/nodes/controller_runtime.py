"""Message-level behaviour of lpv_controller_node, shared with ``lpv-sysid replay``.

No rclpy here: the node shell forwards subscription messages and timer ticks to
:class:`ControllerRuntime`, and ``lpv-sysid replay`` does the same with the messages of a
bag (rosbags classes via ``MsgFactory.rosbags()``), so a replay computes exactly what the
node would have published.

Per tick (``rate_hz``), once started: staleness of every input stream, scheduling box,
the runtime LPV law u = u0(v_d) + K(v_d)(x - x0(v_d)) + R kappa u_e (seed 0 Eq. 31,
control/lpv_controller.py; with the reference feedforward of gains.yaml F_ff/F_jerk the law's
own filtered derivatives of velocity_reference supply a = dv_d/dt and its rate) on x = [phi, theta, u, v, w, p, q, r, Mix Omega] (seed 0
Eq. 14 without position and yaw; delta = Mix Omega, Eq. 7), and its bound monitor. Any
fault (stale / out-of-order / non-finite input, v_d outside the box, bound exceeded,
abort request) latches an abort in :class:`~lpv_sysid.control.safety.SafetySupervisor`:
one ERROR status naming the reason is published and no actuator command follows, so the
bridge hands control back to PX4.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, fields
from typing import Any, Mapping

import numpy as np

from lpv_sysid.control.lpv_controller import LpvController, LpvControllerConfig
from lpv_sysid.control.safety import (EXTERNAL, NON_FINITE, OUT_OF_ORDER, SafetyConfig,
                                      SafetySupervisor)
from lpv_sysid.errors import ConfigError, SafetyError
from lpv_sysid.io import messages as M
from lpv_sysid.io.formats import GainSchedule
from lpv_sysid.models.quadrotor import mixer

LOG = logging.getLogger(__name__)

INPUT_TOPICS = ("state", "rotor_speeds", "velocity_reference", "excitation")
OUTPUT_TOPICS = ("actuator_command", "status")


@dataclass(frozen=True)
class ControllerSettings:
    """The node's parameters (config/lpv_controller.yaml), validated."""

    gains_file: str
    models_file: str = ""
    rate_hz: float = 250.0
    state_timeout_s: float = 0.02
    rotor_timeout_s: float = 0.05
    reference_timeout_s: float = 0.1
    excitation_timeout_s: float = 0.1
    box_margin: float = 0.0
    excitation_gain: float = 1.0          # kappa of seed 0 Eq. (33)
    arm_length: float = 0.225             # mixer of seed 0 Eq. (7) for the saturation
    u_esc_min: float = 0.0
    u_esc_max: float = 1.0
    rate_limit: tuple = ()                # per channel, units of u per second; () = none
    monitor_margin: float = 1.2
    monitor_min_energy: float = 0.05
    monitor_window_s: float = 0.0         # > 0: exponentially forgetting monitor window; 0: running
    feedforward: bool = True              # reference feedforward when gains.yaml has F_ff
    ff_filter_tau: float = 0.05           # s, derivative filter of velocity_reference (a)
    ff_jerk_tau: float = 0.2              # s, its jerk stage (j, when gains.yaml has F_jerk)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "ControllerSettings":
        known = {f.name for f in fields(cls)}
        bad = sorted(set(d) - known)
        if bad:
            raise ConfigError(f"lpv_controller: unknown parameter(s) {bad}")
        if not d.get("gains_file"):
            raise ConfigError("lpv_controller: parameter 'gains_file' is empty: give the "
                              "gains.yaml written by `lpv-sysid synthesize`")
        kw = dict(d)
        kw["rate_limit"] = tuple(float(v) for v in kw.get("rate_limit", ()) or ())
        if not isinstance(kw.get("feedforward", True), bool):
            raise ConfigError(f"lpv_controller: parameter 'feedforward' must be true or false, "
                              f"got {kw['feedforward']!r}")
        for k, v in kw.items():
            if k not in ("gains_file", "models_file", "rate_limit", "feedforward"):
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise ConfigError(f"lpv_controller: parameter '{k}' must be a finite number, "
                                      f"got {v!r}")
                kw[k] = float(v)
        s = cls(**kw)
        if s.rate_hz <= 0:
            raise ConfigError(f"lpv_controller: rate_hz must be > 0, got {s.rate_hz}")
        if s.monitor_window_s < 0 or s.ff_filter_tau < 0 or s.ff_jerk_tau < 0:
            raise ConfigError("lpv_controller: monitor_window_s, ff_filter_tau and ff_jerk_tau must be >= 0")
        return s

    @property
    def timeouts(self) -> dict:
        return {"state": self.state_timeout_s, "rotor_speeds": self.rotor_timeout_s,
                "velocity_reference": self.reference_timeout_s,
                "excitation": self.excitation_timeout_s}


class ControllerRuntime:
    """See module docstring. ``factory`` builds the output messages (MsgFactory)."""

    def __init__(self, settings: ControllerSettings, factory: M.MsgFactory,
                 name: str = "/lpv_sysid/lpv_controller"):
        self.settings = settings
        self.f = factory
        self.name = name
        self.schedule = GainSchedule.load(settings.gains_file, settings.models_file or None)
        self.mix = mixer(settings.arm_length)
        cfg = LpvControllerConfig(
            u_esc_min=settings.u_esc_min, u_esc_max=settings.u_esc_max,
            rate_limit=settings.rate_limit or None, monitor_margin=settings.monitor_margin,
            monitor_min_energy=settings.monitor_min_energy, feedforward=settings.feedforward,
            ff_filter_tau=settings.ff_filter_tau, ff_jerk_tau=settings.ff_jerk_tau,
            monitor_window=settings.monitor_window_s or None)
        self.law = LpvController(self.schedule, cfg, mix=self.mix)
        box = self.schedule.scheduling
        self.supervisor = SafetySupervisor(SafetyConfig(
            timeouts=settings.timeouts, box_min=tuple(box.min), box_max=tuple(box.max),
            box_margin=settings.box_margin))
        self.x8 = None            # phi, theta, u, v, w, p, q, r (FRD)
        self.omega = None         # rotor speeds (4), rad/s
        self.v_d = None           # scheduling / velocity reference (3), FRD
        self.u_e = None           # normalised excitation (4)
        self.commands = 0
        self.flags = {"clamped": 0, "saturated": 0, "rate_limited": 0}
        self._abort_reported = False

    # -- inputs -------------------------------------------------------------------------
    def on_message(self, topic: str, msg, t_now: float) -> None:
        """A message of ``topic`` (one of :data:`INPUT_TOPICS`) received at ``t_now`` [s]."""
        try:
            t, values = parse_input(topic, msg)
        except M.MessageError as exc:
            self.on_bad_message(topic, exc, t_now)
            return
        self.on_sample(topic, t, values, t_now)

    def on_bad_message(self, topic: str, exc: Exception, t_now: float) -> None:
        if self.supervisor.armed:
            self.supervisor.abort(t_now, NON_FINITE, f"{topic}: {exc}")
        else:
            LOG.warning("%s rejected before start: %s", topic, exc)

    def on_sample(self, topic: str, t: float, values: np.ndarray, t_now: float) -> None:
        """Parsed input (see :func:`parse_input`): header time ``t`` [s], ``values``."""
        if topic == "state":
            self.x8 = values
        elif topic == "rotor_speeds":
            self.omega = values
        elif topic == "velocity_reference":
            self.v_d = values[:3]
        else:
            self.u_e = values
        self.supervisor.on_input(topic, t, values, t_now)

    def start(self, t_now: float) -> tuple[bool, str]:
        sup = self.supervisor
        if sup.aborted:
            return False, f"aborted ({sup.event.reason}: {sup.event.detail}); restart the node"
        if sup.armed:
            return False, "already started"
        sup.arm(t_now)
        self.law.reset()
        return True, "LPV control started"

    def abort(self, t_now: float, reason: str = "abort requested") -> str:
        ev = self.supervisor.abort(t_now, EXTERNAL, reason)
        return f"{ev.reason}: {ev.detail}"

    # -- output -------------------------------------------------------------------------
    def tick(self, t_now: float) -> list:
        """``[(topic, msg), ...]`` to publish at ``t_now``: the command, or the abort status."""
        sup = self.supervisor
        out = []
        if not sup.armed:
            return out
        sup.check(t_now)
        ready = self.x8 is not None and self.omega is not None and self.v_d is not None \
            and self.u_e is not None
        if not sup.aborted and ready:
            sup.check_scheduling(t_now, self.v_d)
        if not sup.aborted and ready:
            x12 = np.concatenate([self.x8, self.mix @ self.omega])
            try:
                u, info = self.law.step(t_now, x12, self.v_d,
                                        self.settings.excitation_gain * self.u_e)
            except SafetyError as exc:
                kind = OUT_OF_ORDER if "backwards" in str(exc) else NON_FINITE
                sup.abort(t_now, kind, str(exc))
            else:
                for k in self.flags:
                    self.flags[k] += bool(info[k])
                if info["bound_exceeded"]:
                    sup.on_bound_flag(t_now, True,
                                      f"L2 gain estimate {self.law.gain():.4g} > gamma "
                                      f"{self.law.gamma:g} x margin "
                                      f"{self.settings.monitor_margin:g}")
                if not sup.aborted:
                    self.commands += 1
                    out.append(("actuator_command",
                                M.actuator_command_msg(self.f, round(t_now * 1e9), u)))
        if sup.aborted and not self._abort_reported:
            self._abort_reported = True
            LOG.error("safety abort: %s: %s; actuator commands stopped",
                      sup.event.reason, sup.event.detail)
            out.append(("status", self.status(t_now)))
        return out

    def status(self, t_now: float):
        sup = self.supervisor
        ev = sup.event
        if ev is not None:
            level, message = "ERROR", f"safety abort: {ev.reason}: {ev.detail}"
        elif sup.armed:
            level, message = "OK", "commanding"
        else:
            level, message = "OK", "waiting for start (not commanding)"
        values = {"armed": sup.armed, "aborted": sup.aborted, "commanding": sup.action.commanding,
                  "excitation_on": sup.action.excitation_on,
                  "reason": ev.reason if ev else "", "commands": self.commands,
                  "gain_estimate": self.law.gain(), "gamma": self.law.gamma,
                  **{f"{k}_count": v for k, v in self.flags.items()}}
        st = M.diagnostic_status(self.f, level, self.name, message, values)
        return M.diagnostic_array(self.f, round(t_now * 1e9), [st])


def parse_input(topic: str, msg) -> tuple[float, np.ndarray]:
    """``(header time [s], values)`` of one input message; MessageError when malformed.

    state: ``[phi, theta, u, v, w, p, q, r]`` (FRD); rotor_speeds: Omega (4);
    velocity_reference: ``[u_d, v_d, w_d, r_d]`` (FRD); excitation: u_e (4).
    """
    if topic == "state":
        s = M.state_from_odometry(msg)
        return s.t, np.concatenate([s.euler[:2], s.v_body, s.omega])
    if topic == "rotor_speeds":
        return M.rotor_speeds_from_joint_state(msg)
    if topic == "velocity_reference":
        t, v, r = M.reference_from_twist(msg)
        return t, np.append(v, r)
    if topic == "excitation":
        return M.excitation_from_joint_state(msg)
    raise ConfigError(f"lpv_controller: unknown input topic {topic!r}")


def parse_inputs(topic: str, msgs: list) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised :func:`parse_input` for a whole recording (replay); MessageError names
    the first malformed message."""
    if topic == "state":
        s = M.states_from_odometry(msgs)
        return s.t, np.column_stack([s.euler[:, :2], s.v_body, s.omega])
    if topic == "rotor_speeds":
        return M.channels_from_joint_states(msgs, M.ROTOR_NAMES, field="velocity")
    if topic == "excitation":
        return M.channels_from_joint_states(msgs, M.EXCITATION_NAMES, field="position")
    t = np.empty(len(msgs))
    out = np.empty((len(msgs), 4))
    for i, m in enumerate(msgs):
        t[i], out[i] = parse_input(topic, m)
    return t, out


def load_settings(path: str, node_name: str = "lpv_controller") -> dict:
    """``ros__parameters`` of ``node_name`` from a ROS parameter file (for replay)."""
    import yaml
    try:
        with open(path) as fh:
            data = yaml.safe_load(fh)
    except OSError as exc:
        raise ConfigError(f"{path}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: malformed YAML ({exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of node names")
    for key, body in data.items():
        k = str(key).lstrip("/")
        if k in (node_name, f"**/{node_name}", f"lpv_sysid/{node_name}", "**"):
            if not isinstance(body, dict) or not isinstance(body.get("ros__parameters"), dict):
                raise ConfigError(f"{path}: '{key}' has no 'ros__parameters' mapping")
            return dict(body["ros__parameters"])
    raise ConfigError(f"{path}: no parameters for node '{node_name}' "
                      f"(keys: {sorted(map(str, data))})")


__all__ = ["ControllerRuntime", "ControllerSettings", "INPUT_TOPICS", "OUTPUT_TOPICS",
           "load_settings", "parse_input", "parse_inputs"]
