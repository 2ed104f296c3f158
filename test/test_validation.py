"""lpv_sysid.validation: the shared config checks, and the config classes that use them."""

import math

import pytest

from lpv_sysid.control.baseline import BaselineGains
from lpv_sysid.errors import ConfigError
from lpv_sysid.sim.phase1 import Phase1Config
from lpv_sysid.sim.vehicle import SensorConfig
from lpv_sysid.mavlink.bridge import BridgeConfig
from lpv_sysid.mavlink.link import LinkConfig
from lpv_sysid.mavlink.mavros import MavrosConfig
from lpv_sysid.mavlink.offboard import OffboardConfig
from lpv_sysid.mavlink.sim_vehicle import SimVehicleConfig
from lpv_sysid.validation import check_config_keys, check_keys, is_count, is_finite_number


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


def test_check_config_keys_wording():
    check_config_keys({"url": "x"}, ("url", "baud"), "link")
    with pytest.raises(ConfigError, match=r"^link config must be a mapping, got str$"):
        check_config_keys("url", ("url",), "link")
    with pytest.raises(
        ConfigError, match=r"^unknown link config key\(s\) \['a', 'z'\]; known: \['baud', 'url'\]$"
    ):
        check_config_keys({"z": 1, "a": 2, "url": 3}, ("url", "baud"), "link")


@pytest.mark.parametrize(
    "cls, what",
    [
        (LinkConfig, "link"),
        (OffboardConfig, "offboard"),
        (BridgeConfig, "mavlink bridge"),
        (MavrosConfig, "mavros"),
        (SimVehicleConfig, "sim vehicle"),
    ],
)
def test_mavlink_configs_key_errors(cls, what):
    with pytest.raises(ConfigError, match=rf"^{what} config must be a mapping, got list$"):
        cls.from_dict([])
    with pytest.raises(
        ConfigError, match=rf"^unknown {what} config key\(s\) \['colour'\]; known: "
    ):
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
    with pytest.raises(ConfigError, match=rf"^{section}: unknown key\(s\) \['colour'\]$"):
        cls.from_dict({"colour": "red"})


@pytest.mark.parametrize(
    "make, match",
    [
        (
            lambda: BaselineGains.from_dict({"rate_hz": True}),
            r"controller.rate_hz: must be a finite number",
        ),
        (
            lambda: BaselineGains.from_dict({"rate_hz": math.nan}),
            r"controller.rate_hz: must be a finite number",
        ),
        (
            lambda: SensorConfig.from_dict({"imu_hz": -250.0}),
            r"sim.imu_hz: must be a finite number >= 0",
        ),
        (
            lambda: SensorConfig.from_dict({"seed": True}),
            r"sim.seed: must be a non-negative integer",
        ),
        (
            lambda: SensorConfig.from_dict({"seed": -1}),
            r"sim.seed: must be a non-negative integer",
        ),
        (
            lambda: Phase1Config.from_dict({"taper_s": math.inf}),
            r"phase1.taper_s: must be a finite number >= 0",
        ),
        (
            lambda: Phase1Config.from_dict({"seed": 1.5}),
            r"phase1.seed: must be a non-negative integer",
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
