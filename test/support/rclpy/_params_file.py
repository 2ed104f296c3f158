"""``ros__parameters`` YAML files and ``--ros-args`` parsing (rcl behaviour), stand-in only."""

import re

import yaml

from rclpy.parameter import Parameter


class RCLError(RuntimeError):
    """Mirrors ``rclpy._rclpy_pybind11.RCLError`` raised for bad arguments/files."""


def read(path):
    try:
        with open(path) as fh:
            data = yaml.safe_load(fh)
    except (OSError, yaml.YAMLError) as exc:
        raise RCLError(f"Failed to parse parameters file '{path}': {exc}") from None
    if not isinstance(data, dict):
        raise RCLError(f"Failed to parse parameters file '{path}': not a mapping")
    return data


def _flatten(prefix, value, out):
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}" if prefix else str(k), v, out)
    else:
        out[prefix] = value


def _node_pattern(key):
    key = key.lstrip("/")
    rx = re.escape(key).replace(r"\*\*/", "(.*/)?").replace(r"\*\*", ".*")
    rx = rx.replace(r"\*", "[^/]*")
    return re.compile(rx + r"\Z")


def load_overrides(data, fqn, use_wildcard=True):
    """Parameters for node ``fqn`` (no leading '/') from a parsed params file."""
    out = []
    for key, body in data.items():
        k = str(key)
        matches = (
            k.lstrip("/") == fqn
            if "*" not in k
            else use_wildcard and (_node_pattern(k).match(fqn) is not None)
        )
        if not matches:
            continue
        if not isinstance(body, dict) or "ros__parameters" not in body:
            raise RCLError(f"params file: node '{k}' has no 'ros__parameters' mapping")
        flat = {}
        _flatten("", body["ros__parameters"] or {}, flat)
        for pname, value in flat.items():
            if value == []:
                # rcl's parser: an empty sequence gives no value (NOT_SET)
                out.append(Parameter(pname, Parameter.Type.NOT_SET))
                continue
            if value is None:
                value = "null"  # rcl: YAML null is the string 'null' (also ~)
            try:
                out.append(Parameter(pname, value=value))
            except TypeError as exc:
                raise RCLError(f"params file: parameter '{pname}': {exc}") from None
    return out


def parse_ros_args(args):
    """Return (remaps, param_files, params) from the ``--ros-args`` part of ``args``."""
    remaps, files, params = [], [], []
    if not args:
        return remaps, files, params
    in_ros = False
    it = iter(list(args))
    for a in it:
        if a == "--ros-args":
            in_ros = True
            continue
        if a == "--":
            in_ros = False
            continue
        if not in_ros:
            continue
        if a in ("-r", "--remap"):
            rule = next(it, None)
            if rule is None or ":=" not in rule:
                raise RCLError(f"Couldn't parse remap rule: '{rule}'")
            remaps.append(tuple(rule.split(":=", 1)))
        elif a == "--params-file":
            f = next(it, None)
            if f is None:
                raise RCLError("Couldn't parse params file: missing path")
            files.append(f)
        elif a in ("-p", "--param"):
            rule = next(it, None)
            if rule is None or ":=" not in rule:
                raise RCLError(f"Couldn't parse parameter override rule: '{rule}'")
            pname, text = rule.split(":=", 1)
            params.append(Parameter(pname, value=yaml.safe_load(text)))
        elif a in ("--log-level", "--enclave"):
            next(it, None)
        elif a in (
            "--disable-rosout-logs",
            "--enable-rosout-logs",
            "--disable-stdout-logs",
            "--enable-stdout-logs",
            "--disable-external-lib-logs",
        ):
            pass
        else:
            raise RCLError(f"Found unknown ROS argument: '{a}'")
    return remaps, files, params
