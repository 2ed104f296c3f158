"""The multilinear scheduling weights of seed 0 Eq. (21) on plain floats, for the runtime law
(:mod:`lpv_sysid.control.law.controller`): ``alpha_i(v_d)`` in the vertex order of
``models.lpv.box_vertices`` (the numpy reference is ``models.lpv.multilinear_weights``), with v_d
outside the box clamped onto it and the clamp reported. Plain floats because the 3- and
8-vectors of the quadrotor cost less than numpy's per-call overhead; the 3-axis case is
unrolled (``kron((1-a, a), (1-b, b), (1-c, c))``)."""

from __future__ import annotations


def box_weights(vd: list, lo: list, inv_range: list) -> tuple[list, bool]:
    """alpha(v_d) as floats for the box with lower corner ``lo`` and ``inv_range`` = 1 / (max -
    min) per axis (clamped onto the box), and the clamp flag."""
    if len(lo) == 3:
        # unrolled kron((1-a, a), (1-b, b), (1-c, c)): plain floats are faster than 3 np.kron
        v0, v1, v2 = vd
        l0, l1, l2 = lo
        i0, i1, i2 = inv_range
        a, b, c = (v0 - l0) * i0, (v1 - l1) * i1, (v2 - l2) * i2
        clamped = not (0.0 <= a <= 1.0 and 0.0 <= b <= 1.0 and 0.0 <= c <= 1.0)
        if clamped:
            a = 0.0 if a < 0.0 else 1.0 if a > 1.0 else a
            b = 0.0 if b < 0.0 else 1.0 if b > 1.0 else b
            c = 0.0 if c < 0.0 else 1.0 if c > 1.0 else c
        a0, b0, c0 = 1.0 - a, 1.0 - b, 1.0 - c
        p00, p01, p10, p11 = a0 * b0, a0 * b, a * b0, a * b
        return [
            p00 * c0,
            p00 * c,
            p01 * c0,
            p01 * c,
            p10 * c0,
            p10 * c,
            p11 * c0,
            p11 * c,
        ], clamped
    t = [(v - lk) * ir for v, lk, ir in zip(vd, lo, inv_range)]
    clamped = False
    for k, tk in enumerate(t):
        if tk < 0.0 or tk > 1.0:
            clamped = True
            t[k] = 0.0 if tk < 0.0 else 1.0
    alpha = [1.0]
    for tk in t:
        alpha = [w * f for w in alpha for f in (1.0 - tk, tk)]
    return alpha, clamped
