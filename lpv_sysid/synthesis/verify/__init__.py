"""Independent re-check of a gains certificate (seed 0 Lemma 1, Eqs. 29-31) without the solver.

Checks, each a row of the report:

1. ``hinf``: frozen-parameter closed loops A_i^j + B_i^j K_i at every scheduling vertex and every
   uncertainty vertex, H-infinity norm u_e -> z by Hamiltonian bisection
   (:mod:`lpv_sysid.synthesis.hinf.norm`) <= gamma;
2. ``hinf interior``: the same at random interior scheduling points with the interpolated model
   and gain (Eq. 21, Eq. 31), for the nominal model, for every uncertainty index j when all
   vertices have the same number M of uncertainty vertices (the j-th corners taken together,
   which is the same parameter theta for corner-enumerated polytopes), and for ``n_mix`` random
   corner mixes: A = sum_i alpha_i sum_j w_i^j A_i^j, B = sum_i alpha_i sum_j w_i^j B_i^j with
   Dirichlet weights; for a common input set (``model.common_input``) the weights are the product
   w_i^(a,b) = beta_i^a beta^b with one beta^b for all vertices, so B = sum_b beta^b B^b -- the
   frozen systems the common-B certificate claims (models.lpv_uncertainty module docstring);
2b. ``common B`` / ``product A`` (common input set only): B_i^(a,b) identical to B^b for all
   scheduling vertices i and A-corners a within 1e-12, and A_i^(a,b) independent of b -- the
   structure Lemma 1's interior argument needs; ``verify_files`` also checks that the structure
   is the one the certificate claims and that the B corners span every vertex's identified
   B interval and nominal value (``B hull``);
3. ``region``: closed-loop eigenvalues at all of the above points in the promised LMI region
   (the stability region when none is promised);
4. ``lmi``: when the certificate sidecar is present (sha256 checked), K_i == S_i H^-1 and the
   Eq. (30) LMIs re-evaluated with numpy eigenvalues from the stored X, S, H (after the stored
   diagonal congruence, which preserves inertia) hold at the file's gamma;
4b. element-box certificates (``certificate.certified_set.kind: full_identified_box``, sidecar
   ``lmi_form`` 1-3, :mod:`lpv_sysid.synthesis.robust`), checked without the synthesis code:
   ``box claim`` -- the certified box (sidecar ``box_*``) contains every element interval of the
   models file read here from the raw YAML (:func:`full_box_intervals`, the stored [lower, upper]
   or nominal +/- k std) and its nominal A_i, B_i (elements outside the box equal the file's);
   ``box lmi`` -- the robust LMI re-assembled here in its *uncompressed* Schur form
   [Phi + L T L^T, cal_R^T; cal_R, -T] < 0 (the solver used the compressed harmonic-sum form)
   from the stored X, S, H and multipliers t_l, at every vertex (and, for the rate form, at every
   sign pattern of dv_d/dt from the stored rate bound, the exact condition the solver's W
   relaxation implies); ``small gain`` -- independent of X and H: the KYP-equivalent
   frequency-domain condition at every vertex, ||[C/gamma; T^-1/2 R~ [I; K_i]] (sI - A_cl)^-1
   [B R, L T^1/2] + [0 0; T^-1/2 R~ [0; R] 0]||_inf < 1 (scaled small gain: the vertex bound for
   every delta in the box, Hamiltonian H-inf norm with feedthrough); ``runtime set`` -- every
   system the flight runtime re-checks (sidecar A_sys, B_sys) lies in the certified box;
   ``scheduling`` -- the claimed variation (frozen / arbitrary / rate-bounded) matches the stored
   LMI form and, for rate bounds, the design envelope.
5. ``full-box *`` (optional, :func:`full_box_check`, ``verify_files(full_box=N)``): an *empirical*
5. ``full-box *`` (optional, ``verify_files(full_box=N)``): the *empirical* Monte Carlo over the
   FULL identified box (:mod:`lpv_sysid.synthesis.verify.montecarlo`, intervals by
   :mod:`lpv_sysid.synthesis.verify.intervals`). A full-box certificate (item 4b, the shipped
   configuration, docs/certificate.md) claims that set: the Monte Carlo is a cross-check of the
   claim and a miss fails. A reduced-polytope certificate (``uncertainty.set: reduced_polytope``,
   Eq. 23: ``p_max`` corner parameters, the others at their nominal values) does not claim it: a
   miss is *advisory* (printed ``WARN``) and does not fail the report unless ``strict_full_box``.

Modules: this one loads the files and runs the checks (:func:`verify_files`) and
:func:`record_verification` writes the result to ``verification.yaml``
(:mod:`lpv_sysid.synthesis.verify.report`, the owner of that format, and of the rows);
:mod:`~lpv_sysid.synthesis.verify.frozen` (items 1-4), :mod:`~lpv_sysid.synthesis.verify.box`
(4b), :mod:`~lpv_sysid.synthesis.verify.feedforward` and
:mod:`~lpv_sysid.synthesis.verify.montecarlo` (5, uncertified). Their public names are
importable from here as before.
"""

from __future__ import annotations

from lpv_sysid.synthesis.verify.box import lmi_at_plant
from lpv_sysid.synthesis.verify.checker import (
    VERIFY_SETTINGS,
    record_verification,
    verify_and_record,
    verify_files,
)
from lpv_sysid.synthesis.verify.feedforward import check_feedforward
from lpv_sysid.synthesis.verify.frozen import verify_gains
from lpv_sysid.synthesis.verify.intervals import ElementBox, full_box_intervals
from lpv_sysid.synthesis.verify.montecarlo import element_sensitivities
from lpv_sysid.synthesis.verify.report import Verification, VerifyReport, read_verification

__all__ = [
    "lmi_at_plant",
    "ElementBox",
    "VERIFY_SETTINGS",
    "Verification",
    "VerifyReport",
    "check_feedforward",
    "element_sensitivities",
    "full_box_intervals",
    "read_verification",
    "record_verification",
    "verify_and_record",
    "verify_files",
    "verify_gains",
]
