"""Every guard has a declared sane range (issue 25 item 7).

A guard is a value that decides when the vehicle is protected: a timeout, an age limit, a
margin, a tolerance, a rate limit, an abort bound. Each is declared once (configuration
fields / node parameters) with a finite lower and upper bound, and a value that would
disable the guard (the audit's: bridge ``telemetry_max_age 1e9``, campaign ``state_timeout
1e9``, controller ``rate_limit 1e-9``, which freezes the feedback) is refused on every path:
the configuration file, the dataclass built in code, the node parameter.
"""

from __future__ import annotations

import math
import re

import pytest

from lpv_sysid.configuration import fields as cf
from lpv_sysid.configuration import parameters
from lpv_sysid.control.campaign import CampaignConfig
from lpv_sysid.control.envelope import EnvelopeConfig
from lpv_sysid.control.law import LpvControllerConfig
from lpv_sysid.control.safety import SafetyConfig
from lpv_sysid.errors import ConfigError
from lpv_sysid.flight.campaign import CampaignNodeSettings
from lpv_sysid.flight.controller import ControllerSettings
from lpv_sysid.flight.excitation import ExcitationSettings
from lpv_sysid.mavlink.bridge import BridgeConfig, MavrosConfig
from lpv_sysid.mavlink.link import LinkConfig
from lpv_sysid.mavlink.offboard import OffboardConfig

#: names of guard values (timeouts, ages, margins, tolerances, limits, abort bounds)
GUARD = re.compile(
    r"timeout|max_age|margin|tolerance|rate_limit|abort|max_(tilt|speed|setpoint|body|rotor)"
    r"|floor|ceiling|radius|lookahead|link_timeout|max_retries"
)
CONFIGS = (
    BridgeConfig,
    MavrosConfig,
    LinkConfig,
    OffboardConfig,
    EnvelopeConfig,
    SafetyConfig,
    LpvControllerConfig,
    CampaignConfig,
)
SETTINGS = (ControllerSettings, ExcitationSettings, CampaignNodeSettings)


def _guards():
    for cls in CONFIGS:
        for name, spec in cf.specs(cls).items():
            if GUARD.search(name) and spec.kind in (cf.NUMBER, cf.COUNT, cf.NUMBERS, cf.TABLE):
                item = spec.item if spec.kind == cf.TABLE else spec
                yield f"{cls.__name__}.{name}", item.lo, item.hi
    for cls in SETTINGS:
        for name, (_, spec) in parameters.specs(cls).items():
            if GUARD.search(name) and spec.kind in (parameters.DOUBLE, parameters.DOUBLE_ARRAY):
                yield f"{cls.__name__}.{name}", spec.lo, spec.hi


GUARDS = list(_guards())


def test_the_registry_sees_the_guards_of_the_audit():
    names = {g[0] for g in GUARDS}
    for must in (
        "BridgeConfig.telemetry_max_age",
        "BridgeConfig.command_abort_factor",
        "CampaignConfig.state_timeout",
        "ControllerSettings.rate_limit",
        "LpvControllerConfig.rate_limit",
        "SafetyConfig.timeouts",
        "SafetyConfig.max_body_speed",
        "ControllerSettings.max_rotor_speed",
        "EnvelopeConfig.ceiling",
        "OffboardConfig.input_timeout",
    ):
        assert must in names
    assert len(GUARDS) >= 40


@pytest.mark.parametrize("name, lo, hi", GUARDS, ids=[g[0] for g in GUARDS])
def test_every_guard_has_a_finite_declared_range(name, lo, hi):
    assert lo is not None and hi is not None, name
    assert math.isfinite(lo) and math.isfinite(hi) and lo < hi, (name, lo, hi)


@pytest.mark.parametrize(
    "build, needle",
    [
        (lambda: BridgeConfig.from_dict({"telemetry_max_age": 1e9}), "telemetry_max_age"),
        (lambda: CampaignConfig.from_dict({"state_timeout": 1e9}), "state_timeout"),
        (lambda: ControllerSettings(gains_file="g.yaml", rate_limit=[1e-9] * 4), "rate_limit"),
        (lambda: LpvControllerConfig(rate_limit=(1e-9,) * 4), "rate_limit"),
        (lambda: ControllerSettings(gains_file="g.yaml", envelope_margin=1e9), "envelope_margin"),
        (lambda: BridgeConfig.from_dict({"command_abort_factor": 1e9}), "command_abort_factor"),
        (lambda: BridgeConfig.from_dict({"offboard": {"input_timeout": 1e9}}), "input_timeout"),
    ],
)
def test_values_that_disable_a_guard_are_refused(build, needle):
    with pytest.raises(ConfigError, match=needle):
        build()


def test_rate_limit_range_is_the_same_for_the_node_and_the_law():
    (_, node) = parameters.specs(ControllerSettings)["rate_limit"]
    law = cf.specs(LpvControllerConfig)["rate_limit"]
    assert (node.lo, node.hi) == (law.lo, law.hi) == (0.01, 1000.0)
    ControllerSettings(gains_file="g.yaml", rate_limit=[0.01] * 4)  # the bound itself flies
