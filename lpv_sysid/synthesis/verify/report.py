"""Results of the independent verifier: the rows, the report and its file ``verification.yaml``.

:class:`CheckRow` / :class:`VerifyReport` are what the checks of :mod:`lpv_sysid.synthesis.verify`
append to; :class:`Verification` is the record ``lpv-sysid verify`` writes next to the gains
(:func:`write_verification`, atomically) and ``lpv-sysid report`` reads (:func:`read_verification`)
instead of re-running the verifier. This module is the only owner of that format:

====================  ===========================================================================
``format``            ``lpv_sysid/verification@1``
``passed``            every non-advisory row ok (advisory rows: the empirical full-box Monte Carlo
                      of a certificate that does not claim that set, printed WARN)
``tool_version``      ``lpv_sysid <version>`` that ran the checks
``gains``             ``{file, sha256}``: the gains file checked and the SHA-256 of its bytes
``models``            ``{file, sha256}``: the models file it was checked against
``created``           UTC time of the run (ISO 8601)
``settings``          the verifier's arguments (n_random, seed, full_box, ...)
``numbers``           gamma, gamma_achieved, worst frozen H-inf norm, LMI gamma and margin, small
                      gain, max closed-loop Re(eig), counts (:func:`headline_numbers`)
``per_check``         per check kind: rows, failed, warnings, worst value, limit, result (derived
                      from ``checks``, for a human reader; not read back)
``checks``            every row: ``{check, where, value, limit, ok, note[, advisory]}``
``full_box``          :meth:`FullBoxResult.summary` of the Monte Carlo (when it ran)
====================  ===========================================================================
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

import numpy as np
import yaml

from lpv_sysid.errors import ConfigError

if TYPE_CHECKING:
    from lpv_sysid.synthesis.scaling import Scaling
    from lpv_sysid.synthesis.verify.montecarlo import FullBoxResult

VERIFICATION_FORMAT = "lpv_sysid/verification@1"
#: file name ``lpv-sysid verify`` writes next to the gains file and the report looks for
VERIFICATION_FILE = "verification.yaml"


@dataclass
class CheckRow:
    check: str
    where: str
    value: float
    limit: float
    ok: bool
    note: str = ""
    advisory: bool = False  # empirical check the certificate does not claim: WARN, not FAIL

    @property
    def result(self) -> str:
        return "ok" if self.ok else ("WARN" if self.advisory else "FAIL")


@dataclass
class VerifyReport:
    rows: list = field(default_factory=list)
    full_box: Optional["FullBoxResult"] = None
    gamma: Optional[float] = None  # design gamma of the gains checked (for verification.yaml)
    gamma_achieved: Optional[float] = None  # the certificate's claim

    @property
    def passed(self) -> bool:
        """All rows ok; advisory rows (WARN) do not count."""
        return bool(self.rows) and all(r.ok or r.advisory for r in self.rows)

    @property
    def warnings(self) -> int:
        return sum(1 for r in self.rows if r.advisory and not r.ok)

    def add(self, *a: Any, **kw: Any) -> None:
        self.rows.append(CheckRow(*a, **kw))

    def worst(self, check: str) -> Optional[CheckRow]:
        rows = [r for r in self.rows if r.check == check]
        if not rows:
            return None
        bad = [r for r in rows if not r.ok]
        return (
            bad[0]
            if bad
            else max(rows, key=lambda r: r.value if np.isfinite(r.value) else -np.inf)
        )

    def table(self, max_rows: int = 40) -> str:
        """Failing rows first, then the worst passing row per check."""
        lines = [f"{'check':<14} {'where':<28} {'value':>12} {'limit':>12}  result"]
        shown = [r for r in self.rows if not r.ok][:max_rows]
        for chk in dict.fromkeys(r.check for r in self.rows):
            w = self.worst(chk)
            if w is not None and w.ok:
                shown.append(w)
        for r in shown:
            lines.append(
                f"{r.check:<14} {r.where:<28} {r.value:>12.6g} {r.limit:>12.6g}  "
                f"{r.result}{('  ' + r.note) if r.note else ''}"
            )
        n_bad = sum(not (r.ok or r.advisory) for r in self.rows)
        lines.append(
            f"{len(self.rows)} checks, {n_bad} failed"
            + (f", {self.warnings} warnings (empirical, not certified)" if self.warnings else "")
        )
        return "\n".join(lines)


# --------------------------------------------------------------------------- verification.yaml
def _num(x: Any) -> Optional[float]:
    return None if x is None else float(x)


def headline_numbers(rows: list, gamma: Optional[float], gamma_achieved: Optional[float]) -> dict:
    """The numbers a reviewer asks for, from the rows (None where no such row ran):
    design gamma and the certificate's gamma_achieved; ``worst_hinf``: largest independent frozen
    H-inf norm (rows ``hinf``, ``hinf interior``); ``lmi_gamma`` / ``lmi_margin``: Eq. (30) or
    the element-box LMI re-evaluated (largest gamma, smallest margin); ``small_gain_max``: the
    KYP small-gain value (< 1 passes); ``max_real_eig``: largest closed-loop Re(eig) over the
    ``region`` / continuous ``stability`` rows (its negative is the stability margin)."""

    def vals(*kinds: str) -> list[float]:
        return [
            float(r.value)
            for r in rows
            if r.check in kinds and r.value is not None and math.isfinite(float(r.value))
        ]

    def mx(*kinds: str) -> Optional[float]:
        v = vals(*kinds)
        return max(v) if v else None

    def mn(*kinds: str) -> Optional[float]:
        v = vals(*kinds)
        return min(v) if v else None

    eig = [
        float(r.value)
        for r in rows
        if (r.check == "region" or (r.check == "stability" and r.limit == 0.0))
        and math.isfinite(float(r.value))
    ]
    return {
        "gamma": _num(gamma),
        "gamma_achieved": _num(gamma_achieved),
        "worst_hinf": mx("hinf", "hinf interior"),
        "lmi_gamma": mx("lmi gamma", "box lmi gamma"),
        "lmi_margin": mn("lmi margin", "box lmi margin"),
        "small_gain_max": mx("small gain"),
        "max_real_eig": max(eig) if eig else None,
        "n_checks": len(rows),
        "n_failed": sum(1 for r in rows if not (r.ok or r.advisory)),
        "n_warnings": sum(1 for r in rows if r.advisory and not r.ok),
    }


def _row_dict(r: CheckRow) -> dict:
    d = {
        "check": r.check,
        "where": r.where,
        "value": float(r.value),
        "limit": float(r.limit),
        "ok": bool(r.ok),
        "note": r.note,
    }
    if r.advisory and not r.ok:
        d["advisory"] = True  # WARN: empirical check the certificate does not claim
    return d


@dataclass(frozen=True)
class Verification:
    """One ``verification.yaml`` (module docstring). ``checks``: row mappings as in the file."""

    passed: bool
    tool_version: str
    gains_file: str
    gains_sha256: str
    models_file: str
    models_sha256: str
    created: str
    settings: dict
    numbers: dict
    checks: tuple
    full_box: Optional[dict] = None

    @property
    def failed(self) -> list[dict]:
        """Rows that fail (advisory warnings excluded)."""
        return [c for c in self.checks if not c["ok"] and not c.get("advisory")]

    @property
    def warnings(self) -> list[dict]:
        return [c for c in self.checks if not c["ok"] and c.get("advisory")]

    def per_check(self) -> list[dict]:
        """Per check kind (first-seen order): rows, failed, warnings, worst row (a failing one,
        else the largest finite value), its limit and the kind's result."""
        out = []
        for kind in dict.fromkeys(c["check"] for c in self.checks):
            rows = [c for c in self.checks if c["check"] == kind]
            bad = [c for c in rows if not c["ok"]]
            fin = [c for c in rows if math.isfinite(c["value"])] or rows
            w = bad[0] if bad else max(fin, key=lambda c: c["value"])
            n_fail = sum(1 for c in bad if not c.get("advisory"))
            out.append(
                {
                    "check": kind,
                    "rows": len(rows),
                    "failed": n_fail,
                    "warnings": len(bad) - n_fail,
                    "worst_value": w["value"],
                    "limit": w["limit"],
                    "where": w["where"],
                    "result": "FAIL" if n_fail else ("WARN" if bad else "ok"),
                }
            )
        return out

    def to_dict(self) -> dict:
        d: dict[str, Any] = {
            "format": VERIFICATION_FORMAT,
            "passed": bool(self.passed),
            "tool_version": self.tool_version,
            "gains": {"file": self.gains_file, "sha256": self.gains_sha256},
            "models": {"file": self.models_file, "sha256": self.models_sha256},
            "created": self.created,
            "settings": dict(self.settings),
            "numbers": dict(self.numbers),
            "per_check": self.per_check(),
            "checks": [dict(c) for c in self.checks],
        }
        if self.full_box is not None:
            d["full_box"] = dict(self.full_box)
        return d

    @classmethod
    def from_dict(cls, d: Any, where: str = VERIFICATION_FILE) -> "Verification":
        """Validate a loaded mapping; ConfigError naming ``where`` and the field otherwise.
        ``passed`` must agree with the rows (a file that says passed with a failing row is
        inconsistent, not a pass)."""
        if not isinstance(d, dict):
            raise ConfigError(f"{where}: expected a mapping at the top level")
        if d.get("format") != VERIFICATION_FORMAT:
            raise ConfigError(
                f"{where}: format: expected {VERIFICATION_FORMAT!r}, got {d.get('format')!r}"
            )

        def need(key: str, kind: type, block: Optional[dict] = None, name: str = "") -> Any:
            src = d if block is None else block
            v = src.get(key)
            if not isinstance(v, kind) or (kind is int and isinstance(v, bool)):
                raise ConfigError(
                    f"{where}: {name or key}: expected {kind.__name__}, got {type(v).__name__}"
                )
            return v

        files = {}
        for key in ("gains", "models"):
            blk = need(key, dict)
            files[key] = (
                need("file", str, blk, f"{key}.file"),
                need("sha256", str, blk, f"{key}.sha256"),
            )
            if len(files[key][1]) != 64:
                raise ConfigError(f"{where}: {key}.sha256: expected 64 hex digits")
        checks = []
        for i, c in enumerate(need("checks", list)):
            if not isinstance(c, dict):
                raise ConfigError(f"{where}: checks[{i}]: expected a mapping")
            for key, kind in (("check", str), ("where", str), ("ok", bool)):
                need(key, kind, c, f"checks[{i}].{key}")
            try:
                value, limit = float(c["value"]), float(c["limit"])
            except (KeyError, TypeError, ValueError):
                raise ConfigError(f"{where}: checks[{i}]: value/limit must be numbers") from None
            checks.append({**c, "value": value, "limit": limit, "note": str(c.get("note") or "")})
        passed = need("passed", bool)
        failing = [c for c in checks if not c["ok"] and not c.get("advisory")]
        if passed and (failing or not checks):
            raise ConfigError(
                f"{where}: passed: true contradicts its checks "
                f"({len(failing)} failed of {len(checks)})"
            )
        fb = d.get("full_box")
        return cls(
            passed=passed,
            tool_version=need("tool_version", str),
            gains_file=files["gains"][0],
            gains_sha256=files["gains"][1],
            models_file=files["models"][0],
            models_sha256=files["models"][1],
            created=need("created", str),
            settings=need("settings", dict),
            numbers=need("numbers", dict),
            checks=tuple(checks),
            full_box=fb if isinstance(fb, dict) else None,
        )


def verification_record(
    rep: VerifyReport,
    gains_path: Path | str,
    models_path: Path | str,
    settings: Optional[dict] = None,
) -> Verification:
    """The :class:`Verification` of a finished :class:`VerifyReport` of ``gains_path`` against
    ``models_path`` (both hashed here, after the checks: the record names the bytes checked)."""
    from lpv_sysid import __version__
    from lpv_sysid.io.files import sha256_file

    return Verification(
        passed=bool(rep.passed),
        tool_version=f"lpv_sysid {__version__}",
        gains_file=str(gains_path),
        gains_sha256=sha256_file(gains_path),
        models_file=str(models_path),
        models_sha256=sha256_file(models_path),
        created=_dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        settings=dict(settings or {}),
        numbers=headline_numbers(rep.rows, rep.gamma, rep.gamma_achieved),
        checks=tuple(_row_dict(r) for r in rep.rows),
        full_box=rep.full_box.summary() if rep.full_box is not None else None,
    )


def write_verification(path: Path | str, v: Verification) -> Path:
    """Write ``v`` to ``path`` atomically (temporary file + rename: a reader sees the old file
    or the new one); ConfigError naming the file when it cannot be written."""
    from lpv_sysid.io.files import atomic_write_text

    path = Path(path)
    # libyaml's emitter where PyYAML has it: the same text (compared on the demo's
    # verification.yaml, 4000 full-box samples), 4x faster -- serial time of verify
    dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
    text = yaml.dump(v.to_dict(), Dumper=dumper, sort_keys=False, default_flow_style=None)
    try:
        atomic_write_text(path, text)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write ({exc.strerror or exc})") from None
    return path


def read_verification(path: Path | str) -> Verification:
    """Read and validate a ``verification.yaml`` (ConfigError naming the file and the field)."""
    from lpv_sysid.io.files import read_yaml_mapping

    return Verification.from_dict(read_yaml_mapping(path, finite=False), str(path))


def check_gain_from_certificate(
    rep: VerifyReport,
    i: int,
    K_i: np.ndarray,
    K_cert: np.ndarray,
    sc: Scaling,
    k_rtol: float,
) -> None:
    """Row ``K = S H^-1`` of vertex ``i``: the file's gain against the one the certificate's
    S, H give, compared in the scaled coordinates (relative to the gain's own magnitude
    there)."""
    Ks = K_i * sc.t[None, :] / sc.s_u[:, None]
    Kc = K_cert * sc.t[None, :] / sc.s_u[:, None]
    err = float(np.max(np.abs(Ks - Kc)) / max(np.max(np.abs(Kc)), 1e-300))
    rep.add("K = S H^-1", f"vertex {i}", err, k_rtol, err <= k_rtol)


def check_lmi_data(rep: VerifyReport, cert: dict, R: np.ndarray, C: np.ndarray) -> None:
    """Rows ``lmi data``: the R and C the certificate was computed with (where it records
    them) equal the ones re-derived from the files, to 1e-12 relative."""
    for key, ref in (("R", R), ("C", C)):
        if key in cert:
            same = np.shape(cert[key]) == np.shape(ref) and np.allclose(
                cert[key], ref, rtol=1e-12, atol=0
            )
            rep.add(
                "lmi data",
                key,
                0.0 if same else 1.0,
                0.0,
                bool(same),
                "" if same else f"{key} differs from the one the certificate was computed with",
            )
