"""lpv_sysid.configuration.fields: the shared config checks, the declared-field validator, and the config
classes that use them."""

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
