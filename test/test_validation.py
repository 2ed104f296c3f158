"""lpv_sysid.configuration.fields: the shared config checks, the declared-field validator, and the
config classes that use them."""

import math

import pytest

from lpv_sysid.configuration.fields import (
    check_keys,
    is_count,
    is_finite_number,
)
from lpv_sysid.control.baseline import BaselineGains
from lpv_sysid.errors import ConfigError
from lpv_sysid.mavlink.bridge import BridgeConfig, MavrosConfig
from lpv_sysid.mavlink.link import LinkConfig
from lpv_sysid.mavlink.offboard import OffboardConfig
from lpv_sysid.sim.phase1 import Phase1Config
from lpv_sysid.sim.px4_vehicle import SimVehicleConfig
from lpv_sysid.sim.vehicle import SensorConfig


@pytest.mark.parametrize(
    "v, ok",
    [
        (0, True),
        (-3, True),
        (2.5, True),
        (1e308, True),
        (True, False),
        (False, False),
        (math.nan, False),
        (math.inf, False),
        (-math.inf, False),
        ("1.0", False),
        (None, False),
        ([1.0], False),
    ],
)
def test_is_finite_number(v, ok):
    assert is_finite_number(v) is ok


@pytest.mark.parametrize(
    "v, minimum, ok",
    [
        (0, 0, True),
        (7, 0, True),
        (-1, 0, False),
        (0, 1, False),
        (1, 1, True),
        (True, 0, False),
        (1.0, 0, False),
        ("3", 0, False),
        (None, 0, False),
    ],
)
def test_is_count(v, minimum, ok):
    assert is_count(v, minimum) is ok


def test_check_keys_accepts_and_names_problems_in_order():
    check_keys({"a": 1}, {"a", "b"}, "sec")  # passes silently
    check_keys({}, ("a",), "sec")
    with pytest.raises(ConfigError, match=r"^sec: expected a mapping, got list$"):
        check_keys([("a", 1)], {"a"}, "sec")
    with pytest.raises(ConfigError, match=r"^sec: unknown key\(s\) \['c', 'd'\]$"):
        check_keys({"d": 1, "c": 2, "a": 3}, {"a", "b"}, "sec")
    with pytest.raises(
        ConfigError, match=r"^sec: unknown key\(s\) \['c'\]; allowed \['a', 'b'\]$"
    ):
        check_keys({"c": 2}, {"b", "a"}, "sec", list_allowed=True)
    # unknown keys are reported before missing ones
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['c'\]$"):
        check_keys({"c": 2}, {"a", "b"}, "sec", required={"a"})
    with pytest.raises(ConfigError, match=r"^sec: missing key\(s\) \['a', 'b'\]$"):
        check_keys({}, {"a", "b"}, "sec", required={"b", "a"})


@pytest.mark.parametrize(
    "cls, what",
    [
        (LinkConfig, "link"),
        (OffboardConfig, "offboard"),
        (BridgeConfig, ""),  # the top of the file (BridgeConfig.load names it)
        (MavrosConfig, "mavros"),
        (SimVehicleConfig, "sim_vehicle"),
    ],
)
def test_mavlink_configs_key_errors(cls, what):
    """The MAVLink-side configs refuse a non-mapping and unknown keys in the one wording of
    the declared fields (formerly their own "unknown link config key(s) ..."), naming the
    unknown key and the allowed ones."""
    at = f"{what}: " if what else ""
    with pytest.raises(ConfigError, match=rf"^{at}expected a mapping, got list$"):
        cls.from_dict([])
    with pytest.raises(ConfigError, match=rf"^{at}unknown key\(s\) \['colour'\]; allowed \[.*'"):
        cls.from_dict({"colour": "red"})
    assert isinstance(cls.from_dict({}), cls)


# the config classes keep their section names in the messages
@pytest.mark.parametrize(
    "cls, section",
    [(BaselineGains, "controller"), (SensorConfig, "sim"), (Phase1Config, "phase1")],
)
def test_config_from_dict_key_errors(cls, section):
    with pytest.raises(ConfigError, match=rf"^{section}: expected a mapping, got list$"):
        cls.from_dict([1, 2])
    with pytest.raises(
        ConfigError, match=rf"^{section}: unknown key\(s\) \['colour'\]; allowed \[.*'"
    ):
        cls.from_dict({"colour": "red"})


@pytest.mark.parametrize(
    "make, match",
    [
        (
            lambda: BaselineGains.from_dict({"rate_hz": True}),
            r"^controller\.rate_hz: expected a number, got True$",
        ),
        (
            lambda: BaselineGains.from_dict({"rate_hz": math.nan}),
            r"^controller\.rate_hz: must be finite, got nan$",
        ),
        (
            lambda: SensorConfig.from_dict({"imu_hz": -250.0}),
            r"^sim\.imu_hz: must be > 0, got -250\.0$",
        ),
        (
            lambda: SensorConfig.from_dict({"seed": True}),
            r"^sim\.seed: expected an integer >= 0, got True$",
        ),
        (
            lambda: SensorConfig.from_dict({"seed": -1}),
            r"^sim\.seed: expected an integer >= 0, got -1$",
        ),
        (
            lambda: Phase1Config.from_dict({"taper_s": math.inf}),
            r"^phase1\.taper_s: must be finite, got inf$",
        ),
        (
            lambda: Phase1Config.from_dict({"seed": 1.5}),
            r"^phase1\.seed: expected an integer >= 0, got 1\.5$",
        ),
    ],
)
def test_config_field_errors(make, match):
    with pytest.raises(ConfigError, match=match):
        make()


def test_config_valid_values_round_trip():
    g = BaselineGains.from_dict({"rate_hz": 200, "velocity_rate_hz": 40.0})
    assert g.rate_hz == 200.0 and isinstance(g.rate_hz, float)
    s = SensorConfig.from_dict({"seed": 3, "physics_hz": 1000})
    assert s.seed == 3 and s.physics_hz == 1000.0 and s.decimation(s.state_hz) == 4
    p = Phase1Config.from_dict({"seed": 4, "taper_s": 0})
    assert p.seed == 4 and p.taper_s == 0.0


# ----------------------------------------------------------- declared-field validator
def test_declared_fields_check_type_range_and_keys_with_the_field_path():
    from dataclasses import dataclass

    from lpv_sysid.configuration import fields as cf

    @dataclass(frozen=True)
    class Demo:
        rate: float = cf.number(doc="Hz", lo=0.0, lo_open=True, hi=100.0, unit=" Hz")
        order: int = cf.count(2, lo=1)
        mode: str = cf.choice("a", ("a", "b", "c"))
        band: tuple = cf.numbers((0.0, 1.0), length=2, lo=0.0)
        on: bool = cf.flag(True)

    assert cf.parse_fields(Demo, {"rate": 50, "band": [1, 2]}, "f.yaml") == {
        "rate": 50.0,
        "band": (1.0, 2.0),
    }
    for d, msg in [
        ({}, "f.yaml: missing key(s) ['rate']"),
        ({"rate": 1, "x": 2}, "f.yaml: unknown key(s) ['x']; allowed"),
        ({"rate": 0}, "f.yaml.rate: must be > 0, got 0.0"),
        ({"rate": 200}, "f.yaml.rate: 200 Hz exceeds the limit of 100 Hz"),
        ({"rate": True}, "f.yaml.rate: expected a number, got True"),
        ({"rate": 1, "order": 0}, "f.yaml.order: expected an integer >= 1, got 0"),
        ({"rate": 1, "mode": "d"}, "f.yaml.mode: 'd'; use a, b or c"),
        ({"rate": 1, "band": [1]}, "f.yaml.band: expected 2 values, got 1"),
        ({"rate": 1, "band": [1, -2]}, "f.yaml.band[1]: must be >= 0, got -2.0"),
        ({"rate": 1, "on": "yes"}, "f.yaml.on: expected true or false, got 'yes'"),
    ]:
        with pytest.raises(ConfigError) as e:
            cf.parse_fields(Demo, d, "f.yaml")
        assert str(e.value).startswith(msg), (d, str(e.value))
    # the declaration is the one place the rules live: specs() exposes them
    assert cf.specs(Demo)["rate"].hi == 100.0 and cf.specs(Demo)["mode"].choices == ("a", "b", "c")


def test_signals_and_vrft_configs_use_the_declared_fields():
    from lpv_sysid.configuration import fields as cf
    from lpv_sysid.signals.multisine import GroupConfig, SignalsConfig
    from lpv_sysid.vrft import VrftConfig

    assert cf.specs(SignalsConfig)["duration"].hi == 3600.0
    assert set(cf.specs(GroupConfig)) == {"name", "channels", "band", "energy", "power_fraction"}
    assert set(cf.specs(VrftConfig)) == {"method", "window", "discard", "Ts", "eiv_weight"}
    base = {"duration": 10.0, "sample_rate": 10.0}
    grp = {"name": "g", "channels": ["a"], "band": [0.1, 1.0]}
    with pytest.raises(ConfigError, match=r"^s\.yaml\.groups\[0\]\.band\[0\]: must be >= 0"):
        SignalsConfig.from_dict({**base, "groups": [{**grp, "band": [-1, 1]}]}, "s.yaml")
    with pytest.raises(
        ConfigError, match=r"^s\.yaml\.duration: 4000 s exceeds the limit of 3600 s"
    ):
        SignalsConfig.from_dict({**base, "duration": 4000.0, "groups": [grp]}, "s.yaml")
    with pytest.raises(ConfigError, match=r"^window: expected an integer >= 0, got -1$"):
        VrftConfig.from_dict({"reference_model": {"poles": [0.9]}, "controller": {}, "window": -1})
    cfg = VrftConfig.from_dict(
        {"reference_model": {"poles": [0.9]}, "controller": {}, "Ts": 0.02, "method": "eiv"}
    )
    assert (cfg.method, cfg.window, cfg.Ts, cfg.eiv_weight) == ("eiv", 5, 0.02, "identity")


# ------------------------------------------------------------ field kinds of the validator
def test_list_table_and_matrix_kinds():
    from dataclasses import dataclass

    from lpv_sysid.configuration import fields as cf

    @dataclass(frozen=True)
    class Kinds:
        chans: tuple = cf.counts((1, 2), lo=1, hi=8, unique=True)
        modes: tuple = cf.texts(("HOLD",), choices=("HOLD", "LAND"), fold_case=True, unique=True)
        rates: tuple = cf.table((("A", 1.0),), item=cf.FieldSpec(cf.NUMBER, lo=0.0), pairs=True)
        params: dict = cf.table({}, item=None, choices=("P", "Q"), nullable=True)
        inertia: tuple = cf.matrix(((1.0, 0.0), (0.0, 1.0)), shape=(2, 2))
        noise: tuple = cf.numbers((1.0,), lo=0.0, length=(1, 2), scalar=True)
        bound: object = cf.numbers(None, lo=0.0, choices=("design",), optional=True)
        frac: float = cf.number(0.5, lo=0.0, lo_open=True, hi=1.0, hi_open=True)
        period: float = cf.number(1.0, lo=0.1, section="runner", key="loop_period")

    got = cf.parse_fields(
        Kinds,
        {
            "chans": [3, 1],
            "modes": ["land", "HOLD"],  # compared in upper case, kept as written
            "rates": {"B": 2, "A": 0},
            "params": None,  # null: the default
            "inertia": [[2, 0.5], [0.5, 3]],
            "noise": 0.2,  # a bare number: a list of one
            "bound": "design",
            "runner": {"loop_period": 0.5},
        },
        "k.yaml",
    )
    assert got == {
        "chans": (3, 1),
        "modes": ("land", "HOLD"),
        "rates": (("B", 2.0), ("A", 0.0)),
        "inertia": ((2.0, 0.5), (0.5, 3.0)),
        "noise": (0.2,),
        "bound": "design",
        "period": 0.5,
    }
    for d, msg in [
        ({"chans": [1, 9]}, "k.yaml.chans[1]: 9 exceeds the limit of 8"),
        ({"chans": [2, 2]}, "k.yaml.chans: duplicate values in [2, 2]"),
        ({"chans": []}, "k.yaml.chans: expected a non-empty list of integers"),
        ({"chans": [1.0]}, "k.yaml.chans[0]: expected an integer >= 1, got 1.0"),
        ({"modes": ["hold", "HOLD"]}, "k.yaml.modes: duplicate names in ['hold', 'HOLD']"),
        ({"modes": ["ACRO"]}, "k.yaml.modes[0]: 'ACRO'; use HOLD or LAND"),
        ({"rates": {"A": -1}}, "k.yaml.rates.A: must be >= 0, got -1.0"),
        ({"rates": [1, 2]}, "k.yaml.rates: expected a mapping name: value"),
        ({"params": {"R": 1}}, "k.yaml.params: unknown key(s) ['R']; allowed ['P', 'Q']"),
        ({"inertia": [[1, 0]]}, "k.yaml.inertia: expected 2 rows of 2 numbers"),
        ({"inertia": [[1, 0], [0, "x"]]}, "k.yaml.inertia[1][1]: expected a number"),
        ({"noise": [1, 2, 3]}, "k.yaml.noise: expected 1 or 2 values, got 3"),
        ({"bound": "auto"}, "k.yaml.bound: 'auto'; use design"),
        ({"frac": 1.0}, "k.yaml.frac: 1 must be below 1"),
        ({"runner": {"loop_period": 0.01}}, "k.yaml.runner.loop_period: must be >= 0.1"),
        ({"runner": {"other": 1}}, "k.yaml.runner: unknown key(s) ['other']"),
        ({"runner": 3}, "k.yaml.runner: expected a mapping, got int"),
        ({"loop_period": 1}, "k.yaml: unknown key(s) ['loop_period']"),
    ]:
        with pytest.raises(ConfigError) as e:
            cf.parse_fields(Kinds, d, "k.yaml")
        assert str(e.value).startswith(msg), (d, str(e.value))
    # a dict default is copied per instance; the stored (name, value) pairs check again
    assert Kinds().params == {} and Kinds().params is not Kinds().params
    assert cf.check_fields(Kinds(), "k")["rates"] == (("A", 1.0),)


def test_instances_built_in_code_run_the_declared_checks():
    """check_fields / normalize_fields: the declared rules for a dataclass built in code
    (same paths, numpy scalars are numbers), and the converted values stored."""
    from dataclasses import dataclass

    import numpy as np

    from lpv_sysid.configuration import fields as cf

    @dataclass(frozen=True)
    class Built:
        rate: float = cf.number(1.0, lo=0.0, lo_open=True, hi=10.0)
        idx: tuple = cf.counts((0,))

        def __post_init__(self):
            cf.normalize_fields(self, "built")

    b = Built(rate=np.float32(2.5), idx=[np.int64(3)])
    assert (b.rate, b.idx) == (2.5, (3,)) and type(b.rate) is float and type(b.idx[0]) is int
    with pytest.raises(ConfigError, match=r"^built\.rate: 11 exceeds the limit of 10$"):
        Built(rate=11)
    with pytest.raises(ConfigError, match=r"^built\.idx\[0\]: expected an integer >= 0"):
        Built(idx=(-1,))
    assert str(cf.error("sec", "key", "why")) == "sec.key: why"
    assert str(cf.error("", "key", "why")) == "key: why"
    with pytest.raises(ConfigError, match=r"^link\.url: bad$"):
        cf.under("link.url", lambda: (_ for _ in ()).throw(ConfigError("bad")))
    # a path-less mapping (the top of a file): the reader prefixes the file name
    with pytest.raises(ConfigError, match=r"^unknown key\(s\) \['x'\]; allowed"):
        cf.parse_fields(Built, {"x": 1}, "")


# ------------------------------------------------------------------- guard ranges
def _config_classes():
    from lpv_sysid.control.campaign import CampaignConfig
    from lpv_sysid.control.envelope import EnvelopeConfig
    from lpv_sysid.control.law import LpvControllerConfig
    from lpv_sysid.control.safety import SafetyConfig
    from lpv_sysid.flight.campaign import FlyConfig
    from lpv_sysid.ident.vertex import IdentificationConfig, UncertaintyConfig
    from lpv_sysid.io.recorder import RecorderConfig
    from lpv_sysid.mavlink.telemetry import RotorEstimateConfig
    from lpv_sysid.synthesis.hinf import HinfOptions

    return {
        "LinkConfig": LinkConfig,
        "OffboardConfig": OffboardConfig,
        "RotorEstimateConfig": RotorEstimateConfig,
        "MavrosConfig": MavrosConfig,
        "BridgeConfig": BridgeConfig,
        "EnvelopeConfig": EnvelopeConfig,
        "SimVehicleConfig": SimVehicleConfig,
        "SensorConfig": SensorConfig,
        "Phase1Config": Phase1Config,
        "CampaignConfig": CampaignConfig,
        "FlyConfig": FlyConfig,
        "SafetyConfig": SafetyConfig,
        "LpvControllerConfig": LpvControllerConfig,
        "RecorderConfig": RecorderConfig,
        "IdentificationConfig": IdentificationConfig,
        "UncertaintyConfig": UncertaintyConfig,
        "HinfOptions": HinfOptions,
    }


#: the section path of each class's messages (BridgeConfig, FlyConfig: the file's top)
WHERE = {
    "LinkConfig": "link",
    "OffboardConfig": "offboard",
    "RotorEstimateConfig": "rotor_estimate",
    "MavrosConfig": "mavros",
    "BridgeConfig": "",
    "EnvelopeConfig": "envelope",
    "SimVehicleConfig": "sim_vehicle",
    "SensorConfig": "sim",
    "Phase1Config": "phase1",
    "CampaignConfig": "campaign",
    "FlyConfig": "",
    "SafetyConfig": "safety",
    "LpvControllerConfig": "lpv_controller",
    "RecorderConfig": "recorder",
    "IdentificationConfig": "identification",
    "UncertaintyConfig": "uncertainty",
    "HinfOptions": "hinf",
}
#: keys a class needs besides the one under test
BASE = {
    "SafetyConfig": {"timeouts": {}},
    "RecorderConfig": {"out_dir": "x", "topics": {"/a": "std_msgs/msg/Empty"}},
}
#: (class, key path, values just outside the declared range): timeouts, ages, margins and
#: rates are bounded above (a huge value disables the guard), rate limits and periods below
#: (a tiny value freezes or spins)
GUARDS = [
    ("LinkConfig", "heartbeat_period", (0.049, 5.01)),
    ("LinkConfig", "link_timeout", (0.099, 10.01)),
    ("LinkConfig", "reconnect_period", (0.099, 60.1)),
    ("LinkConfig", "stream_request_period", (0.099, 60.1)),
    ("LinkConfig", "streams.HIGHRES_IMU", (-0.1, 1000.1)),
    ("OffboardConfig", "setpoint_rate_hz", (2.0, 1000.1)),
    ("OffboardConfig", "prestream_time", (1.0, 60.1)),
    ("OffboardConfig", "input_timeout", (0.0099, 2.01)),
    ("OffboardConfig", "ack_timeout", (0.0099, 5.01)),
    ("OffboardConfig", "ack_settle_s", (-0.01, 1.01)),
    ("OffboardConfig", "max_retries", (-1, 11)),
    ("OffboardConfig", "mode_confirm_timeout", (0.0099, 10.01)),
    ("RotorEstimateConfig", "max_gap", (0.0, 2.01)),
    ("RotorEstimateConfig", "esc_timeout", (0.0, 1.01)),
    ("MavrosConfig", "setpoint_rate_hz", (2.0, 1000.1)),
    ("MavrosConfig", "input_timeout", (0.0099, 2.01)),
    ("MavrosConfig", "prestream_timeout", (1.0, 300.1)),
    ("MavrosConfig", "telemetry_max_age", (0.0099, 1.01)),
    ("BridgeConfig", "telemetry_max_age", (0.0099, 1.01)),
    ("BridgeConfig", "n_rotors", (0, 9)),
    ("EnvelopeConfig", "floor", (-0.1, 100.1)),
    ("EnvelopeConfig", "ceiling", (0.0, 500.1)),
    ("EnvelopeConfig", "floor_arm_margin", (-0.1, 10.1)),
    ("EnvelopeConfig", "lookahead", (-0.1, 10.1)),
    ("EnvelopeConfig", "radius", (0.0, 2000.1)),
    ("EnvelopeConfig", "max_tilt_deg", (0.0, 80.1)),
    ("EnvelopeConfig", "max_speed", (0.0, 30.1)),
    ("EnvelopeConfig", "max_setpoint", (0.0, 30.1)),
    ("EnvelopeConfig", "max_setpoint_yaw_rate", (0.0, 6.3)),
    ("SimVehicleConfig", "physics_hz", (49.9, 50_000.1)),
    ("SimVehicleConfig", "stream_rates.HIGHRES_IMU", (-0.1, 1000.1)),
    ("SimVehicleConfig", "verdict_delay_s", (-0.01, 1.01)),
    ("SimVehicleConfig", "odometry_lag_s", (-0.01, 0.11)),
    ("SensorConfig", "physics_hz", (0.0, 50_000.1)),
    ("Phase1Config", "excite_s", (0.0, 3600.1)),
    ("CampaignConfig", "rate_hz", (2.0, 1000.1)),
    ("CampaignConfig", "altitude_max", (0.0, 500.1)),
    ("CampaignConfig", "altitude_margin", (-0.1, 50.1)),
    ("CampaignConfig", "altitude_tolerance", (0.0, 10.1)),
    ("CampaignConfig", "position_tolerance", (0.0, 50.1)),
    ("CampaignConfig", "climb_rate", (0.0, 8.1)),
    ("CampaignConfig", "descent_rate", (0.0, 4.1)),
    ("CampaignConfig", "horizontal_speed", (0.0, 20.1)),
    ("CampaignConfig", "position_gain", (0.0, 5.1)),
    ("CampaignConfig", "hold_gain", (0.0, 5.1)),
    ("CampaignConfig", "hold_max", (0.0, 0.25)),
    ("CampaignConfig", "radius", (0.0, 2000.1)),
    ("CampaignConfig", "settle_dwell", (0.0, 60.1)),
    ("CampaignConfig", "settle_timeout", (0.0, 300.1)),
    ("CampaignConfig", "hover_tolerance", (0.0, 2.1)),
    ("CampaignConfig", "ramp_s", (-0.1, 60.1)),
    ("CampaignConfig", "periods", (0, 101)),
    ("CampaignConfig", "start_timeout", (0.0, 120.1)),
    ("CampaignConfig", "takeoff_timeout", (0.0, 600.1)),
    ("CampaignConfig", "reposition_timeout", (0.0, 600.1)),
    ("CampaignConfig", "recover_timeout", (0.0, 120.1)),
    ("CampaignConfig", "state_timeout", (0.0, 1.01)),
    ("CampaignConfig", "handback_timeout", (0.0, 120.1)),
    ("CampaignConfig", "land_timeout", (0.0, 900.1)),
    ("FlyConfig", "preflight.timeout", (0.49, 120.1)),
    ("FlyConfig", "runner.link_timeout", (0.49, 600.1)),
    ("FlyConfig", "runner.loop_period", (0.00049, 0.051)),
    ("FlyConfig", "runner.status_period", (0.049, 60.1)),
    ("SafetyConfig", "timeouts.state", (0.0, 1.01)),
    ("SafetyConfig", "box_margin", (-0.01, 1.01)),
    ("SafetyConfig", "stamp_tolerance", (-0.01, 0.51)),
    ("LpvControllerConfig", "monitor_margin", (0.99, 10.1)),
    ("LpvControllerConfig", "monitor_min_energy", (0.0, 1.01)),
    ("LpvControllerConfig", "monitor_window", (0.99, 10_000.1)),
    ("LpvControllerConfig", "ff_filter_tau", (-0.01, 2.01)),
    ("LpvControllerConfig", "ff_jerk_tau", (-0.01, 5.01)),
    ("RecorderConfig", "flush_interval_s", (0.0, 1.01)),
    ("RecorderConfig", "reserve_bytes", (-1, (1 << 30) + 1)),
    ("IdentificationConfig", "sample_rate", (0.0, 10_000.1)),
    ("IdentificationConfig", "motor_max_pinned", (-0.01, 1.01)),
    ("UncertaintyConfig", "k_sigma", (0.99,)),
    ("UncertaintyConfig", "max_corners", (0, 65_537)),
    ("UncertaintyConfig", "p_max", (-1, 17)),
    ("UncertaintyConfig", "n_freq", (1, 10_001)),
    ("HinfOptions", "remedy_bisection_steps", (-1, 31)),
    ("HinfOptions", "design_gamma_fraction", (0.0, 1.01)),
]
#: list-valued guards: (class, key, a value with one entry just outside, its path)
LIST_GUARDS = [
    ("LpvControllerConfig", "rate_limit", [1.0, 0.0099, 1.0, 1.0], "rate_limit[1]"),
    ("LpvControllerConfig", "rate_limit", [1.0, 1.0, 1000.1, 1.0], "rate_limit[2]"),
    ("BridgeConfig", "rate_p", [0.0099, 0.15, 0.2], "rate_p[0]"),
    ("BridgeConfig", "rate_p", [0.15, 0.61, 0.2], "rate_p[1]"),
    ("CampaignConfig", "settle_tolerance", [0.3, 0.3, 2.01], "settle_tolerance[2]"),
    ("RotorEstimateConfig", "motor_outputs", [1, 2, 3, 33], "motor_outputs[3]"),
]


def _nested(path: str, value):
    head, _, rest = path.partition(".")
    return {head: _nested(rest, value) if rest else value}


def _refused(name: str, key: str, value, path: str) -> str:
    cls = _config_classes()[name]
    with pytest.raises(ConfigError) as e:
        cls.from_dict({**BASE.get(name, {}), **_nested(key, value)})
    full = f"{WHERE[name]}.{path}" if WHERE[name] else path
    msg = str(e.value)
    assert msg.startswith(f"{full}: "), (name, key, value, msg)
    return msg


@pytest.mark.parametrize("name, key, values", GUARDS, ids=[f"{c}.{k}" for c, k, _ in GUARDS])
def test_a_value_just_outside_each_guard_range_is_refused_naming_the_field(name, key, values):
    for v in values:
        _refused(name, key, v, key)


@pytest.mark.parametrize("name, key, value, path", LIST_GUARDS, ids=[p for *_, p in LIST_GUARDS])
def test_list_guards_name_the_entry(name, key, value, path):
    _refused(name, key, value, path)


def test_hostile_guard_values_are_refused_with_a_clear_message():
    """The values of the hostile-input report: a guard disabled by a huge value or frozen
    by a tiny one never reaches a running core."""
    from lpv_sysid.control.law import LpvControllerConfig

    assert _refused("BridgeConfig", "telemetry_max_age", 1e9, "telemetry_max_age") == (
        "telemetry_max_age: 1e+09 s exceeds the limit of 1 s"
    )
    assert _refused("CampaignConfig", "state_timeout", 1e9, "state_timeout") == (
        "campaign.state_timeout: 1e+09 s exceeds the limit of 1 s"
    )
    assert _refused("LpvControllerConfig", "rate_limit", [1e-9] * 4, "rate_limit[0]") == (
        "lpv_controller.rate_limit[0]: must be >= 0.01, got 1e-09"
    )
    assert _refused("MavrosConfig", "telemetry_max_age", 1e9, "telemetry_max_age").startswith(
        "mavros.telemetry_max_age: 1e+09 s exceeds"
    )
    # built in code (node settings, a library caller): the same declarations
    with pytest.raises(ConfigError, match=r"^lpv_controller\.rate_limit\[0\]: must be >= 0\.01"):
        LpvControllerConfig(rate_limit=(1e-9, 1.0, 1.0, 1.0))
    with pytest.raises(ConfigError, match=r"^link\.link_timeout: 1e\+09 s exceeds"):
        LinkConfig(link_timeout=1e9).validate()
    with pytest.raises(ConfigError, match=r"^offboard\.input_timeout: 1e\+09 s exceeds"):
        OffboardConfig(input_timeout=1e9).validate()
    with pytest.raises(ConfigError, match=r"^telemetry_max_age: 1e\+09 s exceeds"):
        BridgeConfig(telemetry_max_age=1e9).validate()  # BridgeCore calls it


def test_every_converted_config_declares_its_keys():
    """Each configuration class declares its keys once (no hand-written key lists): the
    declared fields plus the nested sections are exactly the keys from_dict accepts."""
    for name, cls in _config_classes().items():
        from lpv_sysid.configuration import fields as cf

        assert cf.specs(cls), name
        with pytest.raises(ConfigError, match=r"unknown key\(s\) \['no_such_key'\]; allowed"):
            cls.from_dict({**BASE.get(name, {}), "no_such_key": 1})


# ------------------------------------------------------------------ shipped configs load
def test_the_shipped_configs_load():
    """Every shipped file read by a declared configuration still loads (the values are the
    ones of before the declarations: dataclass defaults where the file repeats them)."""
    import os

    from lpv_sysid.control.envelope import EnvelopeConfig
    from lpv_sysid.flight.campaign import FlyConfig
    from lpv_sysid.ident.vertex import IdentificationConfig
    from lpv_sysid.io.files import read_yaml, read_yaml_mapping
    from lpv_sysid.sim.phase1 import load_config as load_phase1
    from lpv_sysid.synthesis.gains import SynthesisConfig
    from lpv_sysid.synthesis.hinf import HinfOptions
    from lpv_sysid.vrft import VrftConfig

    config = os.path.join(os.path.dirname(os.path.dirname(__file__)), "lpv_sysid", "config")

    def path(name):
        return os.path.join(config, name)

    for name in ("mavlink_bridge.yaml", "mavlink_bridge_chain.yaml"):
        cfg = BridgeConfig.load(path(name))
        assert cfg.envelope == EnvelopeConfig() and cfg.telemetry_max_age == 0.5
    assert SimVehicleConfig.load(path("sim_vehicle_px4.yaml")) == SimVehicleConfig()
    _, gains, sensors, ph1 = load_phase1(path("quadrotor.yaml"))
    assert (gains, sensors, ph1) == (BaselineGains(), SensorConfig(), Phase1Config())
    ident = IdentificationConfig.from_dict(read_yaml_mapping(path("identification.yaml")))
    assert ident == IdentificationConfig()
    for name in ("campaign.yaml", "campaign_chain.yaml"):
        fly = FlyConfig.load(path(name))
        assert fly.campaign.state_timeout == 0.5 and fly.loop_period == 0.005
        BridgeConfig.load(fly.bridge_config)
    for name in ("synthesis.yaml", "synthesis_chain.yaml", "synthesis_seed_scale.yaml"):
        cfg = SynthesisConfig.load(path(name))
        assert isinstance(cfg.hinf, HinfOptions) and cfg.verify.n_random == 20
    VrftConfig.from_dict(read_yaml(path("vrft_example.yaml")))
