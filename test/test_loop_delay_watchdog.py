"""A watchdog that matches the proof (issue 27 item 3): the controller measures the loop delay
-- the age of the state each command is computed from, header stamp to command time -- and
aborts when it stays above the certified bound for the declared tolerance, long before the
staleness timeouts. Simulated clocks; every time is a multiple of 2^-8 s (and the delays
2^-20 s off the bound), so every sum below is exact in binary floating point."""

import numpy as np
import pytest
from lpv_test_gains import write_gains
from test_controller_safety import feed, hover_inputs, runtime

from lpv_sysid.control.safety import LOOP_DELAY, SafetyConfig, SafetySupervisor
from lpv_sysid.errors import ConfigError

DT = 2.0**-8  # 3.90625 ms: a 256 Hz loop
EPS = 2.0**-20  # ~1 us
T0 = 64.0


def supervisor(bound, tol):
    sup = SafetySupervisor(
        SafetyConfig(timeouts={}, loop_delay_bound=bound, loop_delay_tolerance=tol)
    )
    sup.arm(T0)
    return sup


def commands(sup, delays, t0=T0 + DT):
    """A command every DT from ``t0``, the k-th computed from a state ``delays[k]`` old;
    returns the index of the command that aborted (None: none did)."""
    for k, d in enumerate(delays):
        t = t0 + k * DT
        if sup.check_loop_delay(t, t - d) is not None:
            return k
    return None


def test_sustained_delay_just_above_the_bound_aborts_after_the_tolerance():
    bound, tol = 7 * DT, 5 * DT  # 27.34 ms bound, 19.53 ms tolerance
    sup = supervisor(bound, tol)
    k = commands(sup, [bound + EPS] * 100)
    # above from command 0 at T0 + DT; the command 5 DT later is the first at the tolerance
    assert k == 5
    ev = sup.event
    assert ev.reason == LOOP_DELAY == "loop_delay" and ev.t == T0 + 6 * DT
    assert sup.action.commanding is False
    assert ev.detail == (
        f"loop delay {1e3 * (bound + EPS):.3f} ms (state stamp {T0 + 6 * DT - bound - EPS:.6f} "
        f"s -> command {T0 + 6 * DT:.6f} s) above the certified 27.344 ms for 19.531 ms "
        "(tolerance 19.5312 ms)"
    )


def test_sustained_delay_just_below_the_bound_never_aborts():
    bound, tol = 7 * DT, 5 * DT
    sup = supervisor(bound, tol)
    assert commands(sup, [bound - EPS] * 2560) is None  # 10 s
    assert commands(sup, [bound] * 2560, t0=T0 + 2561 * DT) is None  # at the bound: allowed
    assert sup.event is None


def test_a_run_above_the_bound_restarts_after_a_command_within_it():
    bound, tol = 7 * DT, 5 * DT
    sup = supervisor(bound, tol)
    above, below = bound + EPS, bound - EPS
    # 5 commands above (4 DT < tol), one within, again 5 above: no abort; then a sixth aborts
    assert commands(sup, [above] * 5 + [below] + [above] * 5) is None
    assert commands(sup, [above], t0=T0 + 12 * DT) == 0
    assert sup.event.t == T0 + 12 * DT


def test_zero_tolerance_aborts_on_the_first_command_above_and_zero_bound_is_off():
    sup = supervisor(7 * DT, 0.0)
    assert commands(sup, [7 * DT, 7 * DT + EPS]) == 1
    off = supervisor(0.0, 0.0)
    assert commands(off, [0.5] * 10) is None and off.event is None
    idle = SafetySupervisor(
        SafetyConfig(timeouts={}, loop_delay_bound=DT, loop_delay_tolerance=0.0)
    )
    assert idle.check_loop_delay(T0, T0 - 1.0) is None  # not armed: not judged


@pytest.mark.parametrize(
    "field, value", [("loop_delay_bound", -0.001), ("loop_delay_tolerance", 2.0)]
)
def test_config_bounds(field, value):
    with pytest.raises(ConfigError, match=field):
        SafetyConfig(timeouts={}, **{field: value})


# ------------------------------------------------------------ the controller runtime
@pytest.fixture(scope="module")
def gains(tmp_path_factory):
    return write_gains(tmp_path_factory.mktemp("ld") / "gains.yaml", box=2.0)


@pytest.fixture(scope="module")
def certified_gains(tmp_path_factory):
    def edit(d):
        d["certificate"]["loop_delay"] = {"bound_s": 4 * DT}

    return write_gains(tmp_path_factory.mktemp("ldc") / "gains.yaml", box=2.0, edit=edit)


def fly_delayed(rt, delay, seconds, t0=T0):
    """Every input fresh except the state, stamped ``delay`` before its receipt; a timer tick
    at each receipt (256 Hz). Returns (commands, abort time or None)."""
    x8, _ = hover_inputs(rt)
    feed(rt, t0, stamp=t0 - delay)
    assert rt.start(t0)[0]
    n = 0
    for k in range(1, int(seconds / DT) + 1):
        t = t0 + k * DT
        feed(rt, t, streams=["rotor_speeds", "velocity_reference", "excitation"])
        rt.on_sample("state", t - delay, x8, t)
        n += sum(topic == "actuator_command" for topic, _ in rt.tick(t))
        if rt.supervisor.aborted:
            return n, t
    return n, None


# state timeout 0.05 s + stamp tolerance 0.01 s: every delay below is fresh for the staleness
# checks, which before this watchdog was the only limit on the state's age
SETTINGS = dict(state_timeout_s=0.05, loop_delay_bound_s=6 * DT, loop_delay_tolerance_s=5 * DT)


def test_runtime_aborts_on_a_sustained_delay_just_above_the_bound(gains):
    rt = runtime(gains, **SETTINGS)
    n, t_abort = fly_delayed(rt, 6 * DT + EPS, 2.0)
    ev = rt.supervisor.event
    assert ev.reason == "loop_delay" and t_abort == ev.t == T0 + 6 * DT
    assert n == 5  # commands at T0 + DT ... T0 + 5 DT, none once aborted
    assert ("error", f"safety abort: loop_delay: {ev.detail}; actuator commands stopped") in (
        rt.take_log()
    )


def test_runtime_keeps_commanding_just_below_the_bound(gains):
    rt = runtime(gains, **SETTINGS)
    n, t_abort = fly_delayed(rt, 6 * DT - EPS, 2.0)
    assert t_abort is None and rt.supervisor.event is None and n == 512
    values = {kv.key: kv.value for kv in rt.status(T0 + 2.0).status[0].values}
    assert float(values["loop_delay_max_ms"]) == pytest.approx(1e3 * (6 * DT - EPS), rel=1e-12)
    assert float(values["loop_delay_bound_ms"]) == 1e3 * 6 * DT


def test_runtime_without_a_bound_lets_the_same_delay_pass_and_says_so(gains):
    rt = runtime(gains, state_timeout_s=0.05)
    assert any("loop-delay watchdog is off" in line for _, line in rt.take_log())
    n, t_abort = fly_delayed(rt, 10 * DT, 1.0)  # 39 ms, inside the staleness limit
    assert t_abort is None and n == 256


def test_tick_on_state_measures_receipt_minus_stamp(gains):
    rt = runtime(gains, tick_source="state", **SETTINGS)
    x8, _ = hover_inputs(rt)
    feed(rt, T0, stamp=T0 - 6 * DT - EPS)
    assert rt.start(T0)[0]
    aborted_at = None
    for k in range(1, 200):
        t = T0 + k * DT
        feed(rt, t, streams=["rotor_speeds", "velocity_reference", "excitation"])
        out = rt.on_parsed_input("state", t - 6 * DT - EPS, x8, t)
        if rt.supervisor.aborted:
            aborted_at = t
            break
        assert [topic for topic, _ in out] == ["actuator_command"]
    assert rt.supervisor.event.reason == "loop_delay" and aborted_at == T0 + 6 * DT


def test_certified_bound_is_read_from_the_gains_and_the_parameter_only_tightens(
    certified_gains,
):
    rt = runtime(certified_gains, state_timeout_s=0.05)
    assert rt.supervisor.config.loop_delay_bound == 4 * DT
    assert rt.supervisor.config.loop_delay_tolerance == 0.02  # the declared default
    assert (
        runtime(
            certified_gains, state_timeout_s=0.05, loop_delay_bound_s=3 * DT
        ).supervisor.config.loop_delay_bound
        == 3 * DT
    )
    assert (
        runtime(
            certified_gains, state_timeout_s=0.05, loop_delay_bound_s=0.5
        ).supervisor.config.loop_delay_bound
        == 4 * DT
    )
    n, t_abort = fly_delayed(
        runtime(certified_gains, state_timeout_s=0.05, loop_delay_tolerance_s=0.0),
        4 * DT + EPS,
        1.0,
    )
    assert n == 0 and t_abort == T0 + DT


@pytest.mark.parametrize("bad", [0.0, -0.01, "fast", True, float("nan")])
def test_a_malformed_certified_bound_is_refused(tmp_path, bad):
    def edit(d):
        d["certificate"]["loop_delay"] = {"bound_s": bad}

    # the gains format (its one owner) refuses the file: written or read, never flown
    with pytest.raises(ConfigError, match=r"certificate\.loop_delay\.bound_s: (must be|expected)"):
        runtime(write_gains(tmp_path / "gains.yaml", box=2.0, edit=edit))


def test_a_bound_below_one_state_period_is_refused_with_a_timer_tick(gains):
    with pytest.raises(ConfigError, match="not above one state period"):
        runtime(gains, loop_delay_bound_s=0.004)  # state_rate_hz 250: 4 ms
    rt = runtime(gains, tick_source="state", loop_delay_bound_s=0.004)
    assert rt.supervisor.config.loop_delay_bound == 0.004
    assert np.isclose(1.0 / rt.settings.state_rate_hz, 0.004)
