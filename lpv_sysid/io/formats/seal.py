"""The seal of a gains file: the whole document but the seal, hashed (and optionally keyed).

``seal: {sha256: <hex>[, hmac_sha256: <hex>]}`` is the last top-level entry of ``gains.yaml``.
``sha256`` is SHA-256 of the canonical form of every other entry of the document -- K, the
weights, gamma and the whole ``certificate`` (its ``design`` envelope, ``gains_sha256``,
``sidecar``, and any field a later version adds: nothing is listed here, the document is
hashed as a whole). The canonical form is independent of YAML layout (key order, flow or
block style, number spelling): JSON with sorted keys, no whitespace, floats as their
shortest round-trip repr, ints as ints, tuples as lists, preceded by the tag
``lpv_sysid/gains-seal@1``.

``hmac_sha256`` (optional) is HMAC-SHA256 of the same bytes with an operator key: 32 raw
bytes or 64 hex characters in a key file, the format of a MAVLink signing key
(:func:`load_seal_key`). The unkeyed seal catches every edit of a file (an editor, a
script that forgot to re-certify, a truncated copy), but anyone can recompute it; the keyed
seal says who made the file: only a holder of the key can write one that checks. A loader
given a key requires ``hmac_sha256`` and checks it; without a key only ``sha256`` is checked.

:func:`seal_document` writes the seal (the synthesis, via
:func:`~lpv_sysid.io.formats.gains.certify_law`); :func:`check_seal` is the check every load of
a gains file runs (:meth:`~lpv_sysid.io.formats.gains.GainSchedule.load`).
"""

from __future__ import annotations

import datetime
import hashlib
import hmac
import json
import math
from typing import Any, Mapping, Optional

from lpv_sysid.errors import ConfigError
from lpv_sysid.io.files import read_key

SEAL_KEY = "seal"
SEAL_TAG = b"lpv_sysid/gains-seal@1\n"
_HEX = frozenset("0123456789abcdef")


def _plain(x: Any, path: str) -> Any:
    """``x`` as JSON-ready plain values (ConfigError naming ``path`` for anything else)."""
    if isinstance(x, Mapping):
        out = {}
        for k, v in x.items():
            if not isinstance(k, str):
                raise ConfigError(f"{path}: key {k!r} is not a string (cannot be sealed)")
            out[k] = _plain(v, f"{path}.{k}" if path else k)
        return out
    if isinstance(x, (list, tuple)):
        return [_plain(v, f"{path}[{i}]") for i, v in enumerate(x)]
    if isinstance(x, bool) or x is None or isinstance(x, str):
        return x
    if isinstance(x, int):
        return int(x)
    if isinstance(x, float):
        if not math.isfinite(x):
            raise ConfigError(f"{path}: {x!r} is not finite (cannot be sealed)")
        return float(x)
    if isinstance(x, (datetime.date, datetime.datetime)):
        return {"$date": x.isoformat()}
    if hasattr(x, "item") and callable(x.item):  # a numpy scalar
        return _plain(x.item(), path)
    raise ConfigError(f"{path}: a {type(x).__name__} cannot be sealed")


def canonical_bytes(doc: Mapping[str, Any]) -> bytes:
    """The bytes the seal covers: :data:`SEAL_TAG` + canonical JSON of ``doc`` without
    its ``seal`` entry (module docstring)."""
    body = {k: v for k, v in doc.items() if k != SEAL_KEY}
    text = json.dumps(
        _plain(body, ""), sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False
    )
    return SEAL_TAG + text.encode("ascii")


def seal_of(doc: Mapping[str, Any], key: Optional[bytes] = None) -> dict:
    """The ``seal`` mapping of ``doc`` (with ``hmac_sha256`` when ``key`` is given)."""
    data = canonical_bytes(doc)
    seal = {"sha256": hashlib.sha256(data).hexdigest()}
    if key is not None:
        seal["hmac_sha256"] = hmac.new(key, data, hashlib.sha256).hexdigest()
    return seal


def seal_document(doc: Mapping[str, Any], key: Optional[bytes] = None) -> dict:
    """``doc`` with a fresh ``seal`` as its last entry (a previous seal is replaced)."""
    body = {k: v for k, v in doc.items() if k != SEAL_KEY}
    return {**body, SEAL_KEY: seal_of(body, key)}


def _hex(seal: Mapping, name: str, label: str) -> Optional[str]:
    got = seal.get(name)
    if got is None:
        return None
    if not (isinstance(got, str) and len(got) == 64 and set(got) <= _HEX):
        raise ConfigError(f"{label}: seal.{name}: expected 64 lowercase hex digits, got {got!r}")
    return got


def check_seal(doc: Mapping[str, Any], label: str, key: Optional[bytes] = None) -> str:
    """ConfigError unless ``doc`` carries a seal that matches every other entry (and, with
    ``key``, an ``hmac_sha256`` made with that key); returns what was checked, one line."""
    seal = doc.get(SEAL_KEY)
    if seal is None:
        raise ConfigError(
            f"{label}: seal: missing: the file is not sealed (written by an older version or "
            "assembled by hand); re-run `lpv-sysid synthesize` to write sealed gains"
        )
    if not isinstance(seal, Mapping):
        raise ConfigError(f"{label}: seal: expected a mapping, got {type(seal).__name__}")
    unknown = sorted(set(map(str, seal)) - {"sha256", "hmac_sha256"})
    if unknown:
        raise ConfigError(f"{label}: seal: unknown key(s) {unknown}; allowed sha256, hmac_sha256")
    want = _hex(seal, "sha256", label)
    if want is None:
        raise ConfigError(f"{label}: seal.sha256: missing")
    data = canonical_bytes(doc)
    got = hashlib.sha256(data).hexdigest()
    if not hmac.compare_digest(got, want):
        raise ConfigError(
            f"{label}: seal.sha256: {want} does not match the file (sha256 {got}): an entry "
            "was changed after the file was written (K, the weights, gamma, the certificate "
            "and its design envelope are all sealed); re-run `lpv-sysid synthesize` (and "
            "`lpv-sysid verify`) instead of editing gains"
        )
    mac = _hex(seal, "hmac_sha256", label)
    if key is None:
        return "sealed (sha256)" + (", keyed seal not checked (no key given)" if mac else "")
    if mac is None:
        raise ConfigError(
            f"{label}: seal.hmac_sha256: missing, but a seal key was given: the file was not "
            "sealed with the operator key (anyone can write an unkeyed seal); synthesize it "
            "with the operator key"
        )
    if not hmac.compare_digest(hmac.new(key, data, hashlib.sha256).hexdigest(), mac):
        raise ConfigError(
            f"{label}: seal.hmac_sha256: does not match with the given key: the file was "
            "sealed with another key or changed and re-sealed without the key"
        )
    return "sealed (sha256 and keyed hmac_sha256 checked)"


def load_seal_key(path: str) -> bytes:
    """An operator seal key: 32 raw bytes, or 64 hexadecimal characters (as a MAVLink
    signing key); ConfigError naming the file otherwise."""
    return read_key(path, "seal key file")
