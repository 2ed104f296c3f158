"""lpv_sysid.synthesis: robust polytopic LPV control design and its independent verification.

* ``hinf_lmi``       seed 0 Lemma 1 (Eq. 30) with cvxpy, remedies of Sec. VI, seed-size counts
* ``robust_lmi``     the same bound over the whole element box (S-procedure, one block per vertex;
                     common / per-vertex / rate-bounded Lyapunov matrices), docs/certificate.md
* ``regions``        LMI regions, pole placement, observer, integral action (seed 2 Sec. 5)
* ``scaling``        similarity scaling used inside the LMIs (undone for K)
* ``hinf_norm``      H-infinity norm by Hamiltonian bisection (the independent check)
* ``verify``         certificate re-check (``lpv-sysid verify``)
* ``uncertainty_set`` vertex_models.yaml -> the uncertainty set Lemma 1 certifies (the files
                     themselves: lpv_sysid.io.formats)
* ``example_models`` small reference plants (tests, benchmarks)
"""
