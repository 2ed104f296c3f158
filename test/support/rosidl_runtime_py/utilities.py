"""Stand-in for ``rosidl_runtime_py.utilities``: type lookup by ``pkg/msg/Name``."""

import importlib


def _split(identifier: str, kind: str):
    parts = identifier.split("/")
    if len(parts) == 2:
        parts = [parts[0], kind, parts[1]]
    if len(parts) != 3 or parts[1] != kind or not all(parts):
        raise ValueError(f"Invalid {kind} type: '{identifier}'")
    return parts


def get_interface(identifier: str):
    kind = identifier.split("/")[1] if identifier.count("/") == 2 else "msg"
    return get_message(identifier) if kind == "msg" else get_service(identifier)


def _lookup(identifier: str, kind: str, what: str):
    pkg, _, name = _split(identifier, kind)
    try:
        module = importlib.import_module(f"{pkg}.{kind}")
        return getattr(module, name)
    except (ImportError, AttributeError):
        raise ValueError(f"Invalid {what} type: '{identifier}'") from None


def get_message(identifier: str):
    return _lookup(identifier, "msg", "message")


def get_service(identifier: str):
    return _lookup(identifier, "srv", "service")
