"""Vehicle-link steps of `lpv-sysid fly` around the campaign: wait for the autopilot's
HEARTBEAT, the airborne start check of every run that begins in the air (phase 2, the
broken-loop run), PARAM_SET with the vehicle's confirmation, and a tap that hands PX4's
ATTITUDE_TARGET to the recorder."""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping

from lpv_sysid.errors import SafetyError


def wait_for_vehicle(link, timeout: float, clock, sleep) -> None:
    t0 = clock()
    while clock() - t0 < timeout:
        now = clock()
        link.poll(now)
        link.step(now)
        if link.target_system and link.link_up(now):
            return
        sleep(0.005)
    raise SafetyError(f"no autopilot HEARTBEAT on {link.config.url} within {timeout:g} s")


#: MAV_CMD_REQUEST_MESSAGE and the id of HOME_POSITION
_REQUEST_MESSAGE, _HOME_POSITION = 512, 242.0


def wait_airborne(
    core,
    poll: Callable[[float], Any],
    latest_state: Callable[[], Any],
    clock,
    sleep,
    what: str,
    min_height: float,
    timeout: float = 8.0,
) -> tuple[Any, float]:
    """The start check of a run that begins in the air: ``(state, height above home [m])``.

    Polls up to ``timeout`` s until a state sample, PX4's mode and (when armed) the home
    position are in, asking HOME_POSITION (MAV_CMD_REQUEST_MESSAGE) once a second while it is
    missing; then requires the vehicle armed and at least ``min_height`` m above home (NED:
    height = -(z - z_home); z_home 0 when PX4 never sent a home). :class:`SafetyError` naming
    ``what`` otherwise."""
    t0 = clock()
    next_req = t0
    while clock() - t0 < timeout:
        now = clock()
        poll(now)
        state = latest_state()
        if (
            state is not None
            and core.machine.vehicle_mode is not None
            and (core.envelope.home_position is not None or not core.machine.armed)
        ):
            break
        if now >= next_req:
            next_req = now + 1.0
            core.link.command_long(_REQUEST_MESSAGE, _HOME_POSITION)
        sleep(0.005)
    state = latest_state()
    if state is None:
        raise SafetyError(f"{what}: no state telemetry from the vehicle")
    if not core.machine.armed:
        raise SafetyError(
            f"{what} starts in the air: the vehicle is not armed (fly the campaign with "
            "finish: HOLD first, or take off)"
        )
    hp = core.envelope.home_position
    height = -(float(state.pos_ned[2]) - (float(hp[2]) if hp is not None else 0.0))
    if height < min_height:
        raise SafetyError(
            f"{what} needs >= {min_height:g} m above home, vehicle at {height:.1f} m"
        )
    return state, height


def set_params(
    link, params: Mapping[str, float], clock, sleep, timeout: float = 5.0
) -> list[dict]:
    """PARAM_SET each value (type from a PARAM_REQUEST_READ first) and wait for the
    vehicle's PARAM_VALUE echo with that value; SafetyError when one is not confirmed."""
    from lpv_sysid.mavlink import px4

    done = []
    for name, value in params.items():
        t0 = clock()
        ptype = old = None
        sent_set = -math.inf
        sent_read = -math.inf
        confirmed = False
        while clock() - t0 < timeout and not confirmed:
            now = clock()
            for m in link.poll(now):
                if m.get_type() != "PARAM_VALUE" or m.get_srcSystem() != link.target_system:
                    continue
                if px4.param_id_str(m.param_id) != name:
                    continue
                v = px4.param_from_wire(m.param_value, m.param_type)
                same = math.isclose(
                    float(v), value, rel_tol=1e-6, abs_tol=1e-6
                )  # float32 on the wire
                if ptype is None:
                    ptype, old = int(m.param_type), v
                    confirmed = same  # already set: nothing to change
                elif sent_set > -math.inf and same:
                    confirmed = True
            link.step(now)
            if ptype is None and now - sent_read >= 0.5:
                sent_read = now
                link.send(
                    link.codec.param_request_read_encode(
                        link.target_system, link.target_component, name.encode("ascii"), -1
                    )
                )
            elif ptype is not None and not confirmed and now - sent_set >= 0.5:
                sent_set = now
                link.send(
                    link.codec.param_set_encode(
                        link.target_system,
                        link.target_component,
                        name.encode("ascii"),
                        px4.param_to_wire(value, ptype),
                        ptype,
                    )
                )
            sleep(0.005)
        if not confirmed:
            what = "unknown parameter or no answer" if ptype is None else f"vehicle kept {old}"
            raise SafetyError(
                f"PARAM_SET {name}={value:g} not confirmed within {timeout:g} s ({what})"
            )
        done.append({"name": name, "old": old, "new": value})
    return done


def tap_attitude_target(link, callback: Callable[[float, Any], None]):
    """Wrap ``link.poll`` so every ATTITUDE_TARGET of the link's target reaches
    ``callback(receive_time, [thrust, p_sp, q_sp, r_sp])`` before the bridge sees the message
    (BridgeCore has no raw-message hook; the telemetry decoder ignores ATTITUDE_TARGET), and
    ``link.send`` so the thrust PX4 executes in body-rate OFFBOARD replaces the stale one PX4
    echoes then (:class:`~lpv_sysid.mavlink.bridge.AttitudeTargetEcho`, returned: its counts)."""
    from lpv_sysid.mavlink.bridge import AttitudeTargetEcho

    echo = AttitudeTargetEcho()
    poll, send = link.poll, link.send

    def tapped(now, *a, **kw):
        msgs = poll(now, *a, **kw)
        for m in msgs:
            if m.get_type() == "ATTITUDE_TARGET" and (
                not link.target_system or m.get_srcSystem() == link.target_system
            ):
                got = echo.on_target(m)
                if got is not None:
                    callback(now, got)
        return msgs

    def sent(msg, *a, **kw):
        echo.on_sent(msg)
        return send(msg, *a, **kw)

    link.poll = tapped
    link.send = sent
    return echo


def tap_messages(link, callback: Callable[[float, Any], None]) -> None:
    """Wrap ``link.poll`` so every message of the link's target reaches
    ``callback(receive_time, msg)`` (the vehicle record of ``experiment.yaml``)."""
    poll = link.poll

    def tapped(now, *a, **kw):
        msgs = poll(now, *a, **kw)
        for m in msgs:
            if not link.target_system or m.get_srcSystem() == link.target_system:
                callback(now, m)
        return msgs

    link.poll = tapped


def request_parameter_list(link) -> None:
    """PARAM_REQUEST_LIST to the target: the PX4 parameter snapshot of ``experiment.yaml``
    arrives as PARAM_VALUE while the flight runs (best effort; a lost one is not retried)."""
    try:
        link.send(link.codec.param_request_list_encode(link.target_system, link.target_component))
    except (OSError, AttributeError) as exc:
        import logging

        logging.getLogger(__name__).warning("PARAM_REQUEST_LIST not sent: %s", exc)
