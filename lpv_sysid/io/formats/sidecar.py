"""The certificate sidecar ``<gains stem>.cert.npz`` next to ``gains.yaml``.

It holds the LMI matrices of the certificate: X (N, M, n, n) padded with NaN for vertices with
fewer uncertainty vertices, M_i, S (N, m, n), H (n, n), the scaling t (n,), s_u (m,), R, C; the
certified Eq. (23) systems :data:`SYSTEMS_ARRAYS` for the flight runtime's closed-loop re-check;
for an element-box certificate the box and its multipliers :data:`BOX_ARRAYS`. The gains file's
``certificate.sidecar`` entry references it by file name and sha256, so ``verify`` can
re-evaluate seed 0 Eq. (30) with numpy and the runtime can re-check the certified systems
(:func:`load_certified_systems`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Optional, Sequence

import numpy as np

from lpv_sysid.errors import ConfigError
from lpv_sysid.io.files import check_output, read_npz, sha256_file
from lpv_sysid.io.formats.certificate import Certificate
from lpv_sysid.io.formats.field_checker import FieldChecker

if TYPE_CHECKING:
    from lpv_sysid.models.lpv import ElementBox


#: arrays of the certificate sidecar holding the certified Eq. (23) systems (A_ij, B_ij):
#: ``A_sys`` (N, M, n, n), ``B_sys`` (N, M, n, m), NaN past ``M_sys[i]`` systems at vertex i
SYSTEMS_ARRAYS = ("A_sys", "B_sys", "M_sys")


def systems_arrays(systems: Sequence[Sequence[tuple]]) -> dict:
    """The :data:`SYSTEMS_ARRAYS` of per-vertex lists of ``(A, B)`` (the polytope the
    certificate covers, ``PolytopicModel.systems``), for the sidecar writer."""
    N = len(systems)
    Ms = np.array([len(s) for s in systems], dtype=np.int64)
    n, m = np.asarray(systems[0][0][1]).shape
    A = np.full((N, int(Ms.max()), n, n), np.nan)
    B = np.full((N, int(Ms.max()), n, m), np.nan)
    for i, lst in enumerate(systems):
        for j, (a, b) in enumerate(lst):
            A[i, j], B[i, j] = a, b
    return {"A_sys": A, "B_sys": B, "M_sys": Ms}


def referenced_files(path) -> list[Path]:
    """The files a gains file's certificate refers to (its sidecar), for a command that
    must not overwrite them; ``[]`` for anything that is not a readable gains file (the
    command itself reports that). A file whose text has neither the word ``sidecar`` nor a
    backslash (the only way to spell a key without its letters: a double-quoted escape) has
    no such entry and is not parsed (a models file: ~0.1 s of every command's start-up)."""
    from lpv_sysid.io.files import read_text, strict_load

    p = Path(path)
    try:
        if p.suffix not in (".yaml", ".yml") or not p.is_file():
            return []
        text = read_text(p, p.name, show_path=True)
        if "sidecar" not in text and "\\" not in text:
            return []
        doc = strict_load(text)
        side = doc["certificate"]["sidecar"]["file"]
    except Exception:  # noqa: BLE001 - not a gains file: nothing it refers to
        return []
    return [p.parent / side] if isinstance(side, str) and side else []


def load_certified_systems(
    gains_path, certificate: Certificate, n_x: int, n_u: int, label: Optional[str] = None
) -> list:
    """Per-vertex lists of the certified ``(A_ij, B_ij)`` from the sidecar named in
    ``certificate.sidecar`` (``{file, sha256}``, next to the gains file); ConfigError when
    the entry, the file, its sha256 or the :data:`SYSTEMS_ARRAYS` are missing or wrong."""
    gains_path = Path(gains_path)
    v = FieldChecker(label or gains_path.name)
    side = certificate.extra.get("sidecar")
    if (
        not isinstance(side, Mapping)
        or not isinstance(side.get("file"), str)
        or not isinstance(side.get("sha256"), str)
    ):
        v.fail(
            "certificate.sidecar",
            "missing {file, sha256}: the certified systems cannot be "
            "re-checked; re-run `lpv-sysid synthesize`",
        )
    path = gains_path.parent / side["file"]
    if not path.exists():
        v.fail("certificate.sidecar", f"sidecar {path} not found (copy it next to the gains file)")
    sha = sha256_file(path)
    if sha != side["sha256"]:
        v.fail(
            "certificate.sidecar.sha256",
            f"{side['sha256']} does not match {path.name} "
            f"(sha256 {sha}): the sidecar was changed or belongs to other gains",
        )
    d = read_npz(path, path.name)
    missing = [k for k in SYSTEMS_ARRAYS if k not in d]
    if missing:
        v.fail(
            "certificate.sidecar",
            f"{path.name} has no certified systems {missing} "
            "(written before this check existed); re-run `lpv-sysid synthesize`",
        )
    A, B, Ms = d["A_sys"], d["B_sys"], d["M_sys"]
    N = len(Ms)
    if (
        A.ndim != 4
        or B.ndim != 4
        or A.shape[:2] != B.shape[:2]
        or A.shape[0] != N
        or A.shape[2:] != (n_x, n_x)
        or B.shape[2:] != (n_x, n_u)
        or Ms.ndim != 1
        or np.any(Ms < 1)
        or np.any(Ms > A.shape[1])
    ):
        v.fail(
            "certificate.sidecar",
            f"{path.name}: certified systems have shapes A {A.shape}, "
            f"B {B.shape}, M {Ms.shape}; expected (N, M, {n_x}, {n_x}), (N, M, {n_x}, {n_u})",
        )
    out = []
    for i in range(N):
        a, b = A[i, : int(Ms[i])], B[i, : int(Ms[i])]
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            v.fail(
                "certificate.sidecar",
                f"{path.name}: certified systems of vertex {i} are not finite",
            )
        out.append([(a[j], b[j]) for j in range(int(Ms[i]))])
    return out


#: sidecar arrays of an element-box certificate (synthesis.robust_lmi): the certified box per
#: vertex (``box_rows``/``box_cols`` -1-padded, ``box_half`` NaN-padded, ``box_p``, centres
#: ``box_Ac``, ``box_Bc``), the S-procedure multipliers ``box_t`` (unscaled, t_l of
#: L = h_l e_r, R = e_c^T), the LMI form code ``lmi_form`` (:data:`LMI_FORMS`) and for the
#: rate form the bound ``rate``
BOX_ARRAYS = ("box_rows", "box_cols", "box_half", "box_p", "box_Ac", "box_Bc", "box_t", "lmi_form")
#: ``lmi_form`` codes: which LMI the stored (X, S, H) satisfy
LMI_FORMS = {
    0: "eq30 corners",
    1: "box direct common X",
    2: "box eq30 vertex X_i",
    3: "box eq30 rate X(v_d)",
}


def box_arrays(
    box: "ElementBox", t: Sequence[np.ndarray], form: int, rate: Optional[Sequence[float]] = None
) -> dict:
    """The :data:`BOX_ARRAYS` of an element box and its multipliers, for the sidecar."""
    N, p = box.N, max(box.p) if box.p else 0
    rows = np.full((N, p), -1, dtype=np.int64)
    cols = np.full((N, p), -1, dtype=np.int64)
    half = np.full((N, p), np.nan)
    tt = np.full((N, p), np.nan)
    for i in range(N):
        r, c, h = box.arrays(i)
        rows[i, : r.size], cols[i, : r.size], half[i, : r.size] = r, c, h
        tt[i, : r.size] = np.asarray(t[i], dtype=float)
    out = {
        "box_rows": rows,
        "box_cols": cols,
        "box_half": half,
        "box_p": np.array(box.p, dtype=np.int64),
        "box_Ac": np.asarray(box.A_centre, dtype=float),
        "box_Bc": np.asarray(box.B_centre, dtype=float),
        "box_t": tt,
        "lmi_form": np.array(int(form), dtype=np.int64),
    }
    if rate is not None:
        out["rate"] = np.asarray(rate, dtype=float)
    return out


def save_certificate_npz(
    path: Path | str,
    X: list,
    S: np.ndarray,
    H: np.ndarray,
    t: np.ndarray,
    s_u: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    systems: Optional[Sequence] = None,
    extra: Optional[dict] = None,
) -> str:
    """Write the sidecar; returns its sha256. ``systems`` (per vertex the certified (A_ij, B_ij),
    ``PolytopicModel.systems``) are stored as :data:`SYSTEMS_ARRAYS` for the flight runtime's
    closed-loop re-check; ``extra`` adds arrays (e.g. :func:`box_arrays`)."""
    N = len(X)
    Mi = np.array([len(x) for x in X])
    n = H.shape[0]
    Xa = np.full((N, int(Mi.max()), n, n), np.nan)
    for i in range(N):
        for j in range(Mi[i]):
            Xa[i, j] = X[i][j]
    p = Path(path)
    check_output(p)  # an existing FIFO or device is refused, not opened
    with open(p, "wb") as f:
        arrays = {} if systems is None else systems_arrays(systems)
        arrays.update(extra or {})
        np.savez(
            f,
            X=Xa,
            M=Mi,
            S=np.asarray(S),
            H=np.asarray(H),
            t=np.asarray(t),
            s_u=np.asarray(s_u),
            R=np.asarray(R),
            C=np.asarray(C),
            **arrays,
        )
    return sha256_file(p)


def load_certificate_npz(path: Path | str) -> dict[str, Any]:
    """The sidecar's arrays (ConfigError when unreadable or when the LMI matrices X, M, S, H, t,
    s_u are missing) with ``X_list``: per vertex the M_i Lyapunov matrices X_ij."""
    d: dict[str, Any] = dict(read_npz(path, f"{path}: certificate sidecar"))
    need = {"X", "M", "S", "H", "t", "s_u"}
    if not need <= set(d):
        raise ConfigError(f"{path}: certificate sidecar misses {sorted(need - set(d))}")
    d["X_list"] = [[d["X"][i, j] for j in range(int(d["M"][i]))] for i in range(d["X"].shape[0])]
    return d
