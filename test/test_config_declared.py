"""Every configuration, option and settings dataclass of the package declares its fields once
(issue 19 item 4): each field carries a declaration -- a config field
(:mod:`lpv_sysid.configuration.fields`, metadata ``spec``), a node parameter
(:mod:`lpv_sysid.configuration.parameters`, metadata ``param``) -- or is a nested section, a
dataclass that is itself declared. A new config class with a bare ``x: float = 1.0`` fails here.
"""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil
import re

import lpv_sysid

SUFFIXES = ("Config", "Options", "Settings", "Section")
#: fields that are no declared key, each for a stated reason: state filled in by the class
#: itself, or values parsed by the class's own reader (transfer functions, spectra)
NOT_KEYS = {
    ("FeedforwardSection", "given"),  # whether the file said anything
    ("UncertaintySettings", "reduction"),  # checked by ident.vertex.UncertaintyConfig
    ("FlyConfig", "source"),  # the file it was read from
    ("FlyConfig", "campaign"),  # the nested CampaignConfig (checked as a class of its own)
    ("FlyConfig", "broken_loop"),  # the nested BrokenLoopConfig (a class of its own), or None
    ("GroupConfig", "peak"),  # a number or a list of one per channel (declared FieldSpecs)
    ("GroupConfig", "spectra"),  # breakpoint tables (declared FieldSpecs)
    ("LoopConfig", "M"),  # a transfer-function matrix (vrft.tf.parse_model)
    ("LoopConfig", "prefilter"),  # none | a transfer function
}


def _config_classes():
    seen = {}
    for mod in pkgutil.walk_packages(lpv_sysid.__path__, "lpv_sysid."):
        if mod.name.endswith("__main__") or mod.name.startswith("lpv_sysid.nodes."):
            continue  # rclpy/launch shells: their settings classes live in the runtimes
        m = importlib.import_module(mod.name)
        for name, obj in vars(m).items():
            if (
                isinstance(obj, type)
                and obj.__module__ == m.__name__
                and name.endswith(SUFFIXES)
                and dataclasses.is_dataclass(obj)
            ):
                seen[f"{m.__name__}.{name}"] = obj
    return seen


def _undeclared(cls) -> list[str]:
    out = []
    for f in dataclasses.fields(cls):
        if "spec" in f.metadata or "param" in f.metadata or (cls.__name__, f.name) in NOT_KEYS:
            continue
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else None
        if dataclasses.is_dataclass(default) or (
            isinstance(f.type, str) and set(re.findall(r"\w+", f.type)) & _names
        ):
            continue  # a nested section (checked as a class of its own)
        out.append(f.name)
    return out


_classes = _config_classes()
_names = {c.__name__ for c in _classes.values()} | {
    "Region",
    "FeedforwardLayout",
    "ControllerSpec",
}


def test_there_are_config_classes_to_check():
    assert len(_classes) >= 30, sorted(_classes)


def test_every_config_field_is_declared():
    bad = {name: _undeclared(cls) for name, cls in _classes.items()}
    bad = {k: v for k, v in bad.items() if v}
    assert not bad, f"fields without a declaration (configuration.fields / parameters): {bad}"


def test_a_bare_field_is_caught():
    @dataclasses.dataclass(frozen=True)
    class DemoConfig:
        x: float = 1.0

    assert _undeclared(DemoConfig) == ["x"]
