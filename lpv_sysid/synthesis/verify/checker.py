"""The verification of a gains file against its models file (:func:`verify_files`), its
full-box rows and its record (:func:`verify_and_record`); the method is the
:mod:`lpv_sysid.synthesis.verify` docstring."""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any, Optional

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.synthesis.regions import Region
from lpv_sysid.synthesis.verify.box import (
    _sidecar_box,
    check_box_claim,
    check_joint_claim,
    check_robust_claim,
    check_scheduling_claim,
)
from lpv_sysid.synthesis.verify.feedforward import check_feedforward
from lpv_sysid.synthesis.verify.frozen import _check_input_claim, verify_gains
from lpv_sysid.synthesis.verify.intervals import full_box_intervals
from lpv_sysid.synthesis.verify.montecarlo import FullBoxResult, start_full_box_check
from lpv_sysid.synthesis.verify.report import (
    VERIFICATION_FILE,
    VerifyReport,
    verification_record,
    write_verification,
)

log = logging.getLogger(__name__)


def verify_files(
    gains_path: Path | str,
    models_path: Path | str,
    n_random: int = 20,
    seed: int = 0,
    uncertainty: Optional[dict] = None,
    velocity_index=None,
    full_box: int = 0,
    strict_full_box: bool = False,
    k_sigma: Optional[float] = None,
    full_box_kept: str = "stored",
    workers: Optional[int] = 1,
    backend: str = "process",
    seal_key: Optional[bytes] = None,
    loop_delay_s: Optional[float] = None,
) -> VerifyReport:
    """Load gains.yaml (+ sidecar) and vertex_models.yaml and run :func:`verify_gains`.

    ``loop delay``: the certificate's ``loop_delay.bound_s`` re-proven (the D-scaled small gain
    of :mod:`lpv_sysid.synthesis.delay` on every stored frozen system); ``loop_delay_s`` (the
    configured loop's worst delay, :func:`lpv_sysid.synthesis.delay.configured_delay_s`) must
    not exceed it.

    Also checks names, box, equilibria and the models_sha256 of the certificate. ``full_box`` > 0
    adds the empirical Monte Carlo check over the full identified box (module docstring item 5,
    :func:`full_box_check` with ``seed``); its rows are advisory (WARN, ``passed`` unaffected)
    unless ``strict_full_box`` or the certificate claims the full box (then a miss fails: the
    Monte Carlo is a cross-check of the claim). ``k_sigma`` overrides the models file's
    ``meta.k_sigma``. ``workers``: processes of the full-box Monte Carlo (``None``: every core;
    the numbers do not depend on it), on ``backend`` (``process`` or ``dask``).
    """
    from lpv_sysid.io.files import sha256_file
    from lpv_sysid.io.formats import GainSchedule, load_certificate_npz
    from lpv_sysid.synthesis.hinf import performance_matrix
    from lpv_sysid.synthesis.uncertainty_set import load_models

    check_counts(n_random, seed, full_box)

    # the reading the vehicle flies (io.formats; LpvController takes the same GainSchedule)
    # the one load: structure, the law against certificate.gains_sha256, the whole file
    # against its seal (with seal_key: the operator's keyed seal too)
    gains = GainSchedule.load(gains_path, auto_layout=True, key=seal_key)
    cert = gains.certificate.to_dict()
    claim = cert.get("input_structure")
    if uncertainty is not None:
        unc_cfg = uncertainty
    else:
        # rebuild the polytope the certificate was solved for; certificates without an
        # input_structure entry predate the common-B option and are per-vertex
        unc_raw = cert.get("uncertainty") or {}
        if not isinstance(unc_raw, dict):
            raise ConfigError(
                f"{gains_path}: certificate.uncertainty must be a mapping, got {unc_raw!r}"
            )
        unc_cfg = dict(unc_raw)
        unc_cfg["common_b"] = isinstance(claim, dict) and claim.get("B") == "common"
    model, raw = load_models(models_path, unc_cfg)
    ga_claim = cert.get("gamma_achieved")
    rep = VerifyReport(
        gamma=float(gains.gamma), gamma_achieved=None if ga_claim is None else float(ga_claim)
    )
    sha = sha256_file(models_path)
    rep.add(
        "models hash",
        Path(models_path).name,
        0.0 if sha == cert.get("models_sha256") else 1.0,
        0.0,
        sha == cert.get("models_sha256"),
        ""
        if sha == cert.get("models_sha256")
        else "models file differs from the one the gains were synthesised for",
    )
    same_names = (
        gains.state_names == model.state_names
        and gains.input_names == model.input_names
        and gains.scheduling.names == model.scheduling_names
    )
    rep.add("names", "states/inputs/scheduling", 0.0 if same_names else 1.0, 0.0, same_names)
    same_box = np.allclose(gains.vmin, model.vmin) and np.allclose(gains.vmax, model.vmax)
    rep.add("box", "scheduling min/max", 0.0 if same_box else 1.0, 0.0, bool(same_box))
    eq_err = float(max(np.max(np.abs(gains.x0 - model.x0)), np.max(np.abs(gains.u0 - model.u0))))
    rep.add("equilibria", "x0/u0 vs models", eq_err, 1e-9, eq_err <= 1e-9)
    if not (same_names and same_box):
        return rep
    _check_input_claim(rep, model, claim, raw)
    if gains.F_ff is not None and gains.feedforward is not None:
        check_feedforward(rep, model, gains.F_ff, gains.feedforward.to_dict(), gains.F_jerk)
    region = Region.from_dict(cert.get("region")) if cert.get("region") else None
    sidecar = None
    side = cert.get("sidecar")
    if isinstance(side, dict) and side.get("file"):
        p = Path(gains_path).parent / str(side["file"])
        if not os.path.lexists(p):
            rep.add("sidecar", p.name, 1.0, 0.0, False, "certificate sidecar missing")
        else:
            # present but unreadable (not a regular file, empty, truncated, corrupt): a damaged
            # input, ConfigError (exit 2), not a failed verification; readable but altered: FAIL
            load_certificate_npz(p)
            ok = sha256_file(p) == side.get("sha256")
            rep.add(
                "sidecar", p.name, 0.0 if ok else 1.0, 0.0, ok, "" if ok else "sha256 mismatch"
            )
            if ok:
                sidecar = load_certificate_npz(p)
    if velocity_index is None and cert.get("velocity_states"):
        try:
            velocity_index = tuple(model.state_names.index(nm) for nm in cert["velocity_states"])
        except ValueError:
            rep.add(
                "velocity",
                "certificate.velocity_states",
                1.0,
                0.0,
                False,
                "names not among the states",
            )
            return rep
    if velocity_index is None:
        names = ("u", "v", "w")
        velocity_index = (
            tuple(model.state_names.index(n) for n in names)
            if all(n in model.state_names for n in names)
            else (2, 3, 4)
        )
    C = performance_matrix(gains.Q, model.n_x, velocity_index)
    mc = None  # the full-box Monte Carlo runs on its workers while the checks below run here
    if full_box > 0:
        boxes, k, k_src = full_box_intervals(raw, k_sigma, full_box_kept)
        mc = start_full_box_check(
            model,
            gains.K,
            gains.R,
            C,
            gains.gamma,
            boxes,
            n=full_box,
            seed=seed,
            k_sigma=k,
            k_source=k_src,
            workers=workers,
            backend=backend,
        )
    if model.box is not None:
        bx = _sidecar_box(sidecar, model.n_x, model.n_u) if sidecar is not None else None
        if bx is None:
            rep.add(
                "box claim",
                "sidecar",
                1.0,
                0.0,
                False,
                "full-box certificate without its box arrays",
            )
        else:
            check_box_claim(rep, model, raw, cert, bx)
            check_joint_claim(rep, model, raw, cert, bx)
            check_robust_claim(rep, model, raw, cert, bx)
    check_scheduling_claim(rep, cert, sidecar)
    sub = verify_gains(
        model, gains.K, gains.R, C, gains.gamma, region, n_random, seed, certificate=sidecar
    )
    rep.rows.extend(sub.rows)
    ga = cert.get("gamma_achieved")
    if ga is not None:
        worst = max(
            (r.value for r in rep.rows if r.check.startswith("hinf")), default=float("nan")
        )
        rep.add(
            "gamma claim",
            "certificate.gamma_achieved",
            worst,
            float(ga) * (1 + 1e-3) + 1e-12,
            bool(worst <= float(ga) * (1 + 1e-3) + 1e-12),
            "worst independent H-inf norm vs the claimed gamma_achieved",
        )
    _check_loop_delay(rep, model, gains, C, loop_delay_s)
    if mc is not None:
        res = mc.result()
        claimed = (
            isinstance(cert.get("certified_set"), dict)
            and cert["certified_set"].get("kind") == "full_identified_box"
            and k_sigma is None
            and full_box_kept == "stored"
        )
        add_full_box_rows(rep, res, strict=strict_full_box, claimed=claimed)
    return rep


def record_verification(
    gains_path: Path | str,
    models_path: Path | str,
    out: Optional[Path | str] = None,
    **kw: Any,
) -> tuple[VerifyReport, Path]:
    """:func:`verify_files` (``kw`` its options) and the result written to ``out`` (default
    ``verification.yaml`` next to the gains file) with the SHA-256 of the files checked;
    returns (report, path). The file is written for a failed verification too (passed: false)."""
    rep = verify_files(gains_path, models_path, **kw)
    path = Path(out) if out is not None else Path(gains_path).parent / VERIFICATION_FILE
    settings = {k: v for k, v in kw.items() if k not in ("uncertainty", "velocity_index")}
    write_verification(path, verification_record(rep, gains_path, models_path, settings))
    return rep, path


def add_full_box_rows(
    rep: VerifyReport, res: FullBoxResult, strict: bool = False, claimed: bool = False
) -> None:
    """Rows ``full-box hinf`` / ``full-box frac`` / ``full-box stab``: ``ok`` only when every
    sample passes; otherwise advisory (WARN) unless ``strict``. ``claimed``: the certificate
    claims this box (``certified_set.kind: full_identified_box``), so a miss is a broken
    certificate (strict)."""
    rep.full_box = res
    adv = not (strict or claimed)
    w = res.worst
    vd = "[" + ", ".join(f"{x:.3g}" for x in w.v_d) + "]" if w is not None else "-"
    tag = f"empirical, {res.n} samples, k={res.k_sigma:g}; " + (
        "cross-check of the certified full box" if claimed else "not certified"
    )
    if w is not None and not np.isnan(w.norm):
        rep.add(
            "full-box hinf",
            f"worst v_d {vd}",
            w.norm,
            res.gamma,
            res.passed,
            f"{w.where}; {tag}",
            advisory=adv,
        )
    n_ok = sum(s.ok for s in res.samples)
    rep.add(
        "full-box frac",
        f"{n_ok}/{res.n} samples ok",
        res.fraction_ok,
        1.0,
        res.passed,
        "fraction with norm <= gamma and stable",
        advisory=adv,
    )
    n_unst = sum(s.abscissa >= 0 for s in res.samples)
    rep.add(
        "full-box stab",
        "max Re eig" if res.worst is None or not np.isnan(res.worst.norm) else "max |eig| - 1",
        res.max_abscissa,
        0.0,
        res.all_stable,
        "" if res.all_stable else f"{n_unst} unstable samples",
        advisory=adv,
    )


#: the settings of ``lpv-sysid verify`` (its command-line defaults) and of the verification
#: the PX4 chain records after a synthesis
VERIFY_SETTINGS: dict[str, Any] = {
    "n_random": 20,
    "seed": 0,
    "full_box": 200,
    "strict_full_box": False,
    "k_sigma": None,
    "full_box_kept": "stored",
    "loop_delay_s": None,
}


#: bounds of verify's counts (checked before anything is drawn or allocated)
MAX_RANDOM = 100_000
MAX_FULL_BOX = 100_000
MAX_SEED = 2**32 - 1


def check_counts(n_random: int, seed: int, full_box: int) -> None:
    """ConfigError naming the flag: ``--random`` in 0 .. MAX_RANDOM, ``--seed`` in
    0 .. 2^32 - 1 (numpy's seed range), ``--full-box`` in 0 .. MAX_FULL_BOX."""
    for flag, value, hi in (
        ("--random", n_random, MAX_RANDOM),
        ("--seed", seed, MAX_SEED),
        ("--full-box", full_box, MAX_FULL_BOX),
    ):
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= hi:
            raise ConfigError(f"{flag} {value!r}: must be an integer in 0 .. {hi}")


def verify_and_record(
    gains_path: Path | str,
    models_path: Path | str,
    out: Optional[Path | str] = None,
    workers: Optional[int] = 1,
    backend: str = "process",
    seal_key: Optional[bytes] = None,
    **settings: Any,
) -> tuple[VerifyReport, Path]:
    """:func:`verify_files` with :data:`VERIFY_SETTINGS` (overridden by ``settings``), its
    record written to ``out`` (default: ``verification.yaml`` next to the gains file).
    ``workers`` and ``backend`` (not settings: the record does not depend on them) go to
    :func:`verify_files`.
    Returns the report and the record's path."""
    used = {**VERIFY_SETTINGS, **settings}
    rep = verify_files(
        gains_path, models_path, **used, workers=workers, backend=backend, seal_key=seal_key
    )
    path = Path(out) if out else Path(gains_path).parent / VERIFICATION_FILE
    write_verification(path, verification_record(rep, gains_path, models_path, used))
    return rep, path


def _check_loop_delay(
    rep: VerifyReport, model, gains, C: np.ndarray, configured: Optional[float]
) -> None:
    """Rows ``loop delay`` (the bound re-proven) and ``loop config`` (a configured delay within
    it); a certificate without ``loop_delay`` (written before issue 20) gets a WARN: no delay
    is covered."""
    from lpv_sysid.synthesis import delay as dl

    bound = gains.certificate.loop_delay_bound_s
    if bound is None:
        rep.add(
            "loop delay",
            "certificate.loop_delay",
            float("nan"),
            float("nan"),
            False,
            "the certificate states no loop-delay bound: no delay is covered (synthesize again)",
            advisory=True,
        )
        return
    ok, worst, where = dl.covers(model.systems, gains.K, gains.R, C, float(gains.gamma), bound)
    rep.add(
        "loop delay",
        f"{bound * 1e3:.2f} ms, {where}",
        worst,
        1.0,
        bool(ok),
        "D-scaled small gain at the bound (< 1: ||u_e -> z|| < gamma for every constant delay "
        "<= bound on the stored frozen systems)",
    )
    if configured is not None:
        rep.add(
            "loop config",
            "configured loop delay",
            float(configured),
            bound,
            bool(configured <= bound),
            "" if configured <= bound else "the configured loop is slower than the certificate",
        )
