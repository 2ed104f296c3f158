"""lpv_sysid.synthesis: robust polytopic LPV control design and its independent verification.

* ``hinf_lmi``       seed 0 Lemma 1 (Eq. 30): solver driving and the remedies of Sec. VI;
                     its parts: ``hinf_options`` (options, results, problem size),
                     ``lemma1_numeric`` (Eqs. 19b, 27, 28, 30 in numpy: the re-check),
                     ``lemma1_cvxpy`` (Eq. 30 as a cvxpy problem), ``hinf_box`` (the box route)
* ``robust_lmi``     the same bound over the whole element box (S-procedure, one block per vertex;
                     common / per-vertex / rate-bounded Lyapunov matrices), docs/certificate.md;
                     its parts: ``robust_box_data`` (scaling, element maps),
                     ``robust_box_problem`` (the cvxpy problem),
                     ``robust_box_check`` (the numpy re-check)
* ``regions``        LMI regions, pole placement, observer, integral action (seed 2 Sec. 5)
* ``scaling``        similarity scaling used inside the LMIs (undone for K)
* ``hinf_norm``      H-infinity norm by Hamiltonian bisection (the independent check)
* ``verify``         certificate re-check (``lpv-sysid verify``): ``verify_frozen``,
                     ``verify_box``, ``verify_feedforward`` (certified checks),
                     ``element_intervals``, ``full_box_montecarlo`` (uncertified evidence),
                     ``verify_report`` (results and the verification.yaml format)
* ``uncertainty_set`` vertex_models.yaml -> the uncertainty set Lemma 1 certifies (the files
                     themselves: lpv_sysid.io.formats)
* ``example_models`` small reference plants (tests, benchmarks)
"""
