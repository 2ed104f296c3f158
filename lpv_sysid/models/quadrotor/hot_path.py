"""The simulation's hot path of the seed 0 quadrotor, generated as Python source per model.

Why code generation: the simulators take one RK4 step of the 16-state model (seed 0
Eqs. 3, 6-8) per physics tick, so the step's cost is the simulation's cost. The package
may not depend on compiled code (no numba, no C extension, no compiler at install time)
and numpy's per-call overhead dominates on 3- and 4-vectors, so the fastest step pure
CPython can take is straight-line float arithmetic on locals. The equations are
therefore written once below as source text; :func:`compile_hot_path` specialises that
source on one model's parameter values (:class:`_Specialise`: literals instead of names,
zero terms dropped, bit-identical results) and compiles it. bench/bench_phase1.py
measures the step against the CPython floor of its arithmetic.
"""

from __future__ import annotations

import ast
import functools
from typing import Any, Mapping

import numpy as np

from lpv_sysid.models.quadrotor.params import K_NAMES, QuadrotorParams
from lpv_sysid.models.quadrotor.states import HALF_SQRT2

# ---------------------------------------------------------------- hot-path equations
# The equations of the simulation's hot path, written once as source text and compiled per
# model (every parameter a closure constant, every state a plain-float local): the rotor
# model of Eq. (8), the aerodynamic forces and moments of Eq. (6) and the rigid-body
# equations of Eq. (3). From them the model builds ``_fm`` (F, M), ``_rotor_rates``
# (Omega-dot), ``derivatives_list`` (the 16-state derivative) and ``rk4_step`` (one classical
# Runge-Kutta step with the command held, the four derivative evaluations inlined: no
# calls, lists or attribute lookups between the stages). CPython executes the same float
# operations in the same order in all four, so they agree bit for bit.
# Names: body velocity u, v, w; rates p, q, r; rotor speeds O1..O4; command c0..c3.

_SRC_ESC = """
e1 = mi00 * c0 + mi01 * c1 + mi02 * c2 + mi03 * c3
e1 = 0.0 if e1 < 0.0 else (1.0 if e1 > 1.0 else e1)
e2 = mi10 * c0 + mi11 * c1 + mi12 * c2 + mi13 * c3
e2 = 0.0 if e2 < 0.0 else (1.0 if e2 > 1.0 else e2)
e3 = mi20 * c0 + mi21 * c1 + mi22 * c2 + mi23 * c3
e3 = 0.0 if e3 < 0.0 else (1.0 if e3 > 1.0 else e3)
e4 = mi30 * c0 + mi31 * c1 + mi32 * c2 + mi33 * c3
e4 = 0.0 if e4 < 0.0 else (1.0 if e4 > 1.0 else e4)
be1 = b_om * e1
be2 = b_om * e2
be3 = b_om * e3
be4 = b_om * e4
"""
# Eq. (8): u_ESC = clip(Mix^-1 u, 0, 1) (e1..e4 above, be = b_Omega u_ESC: computed once per
# held command); Omega-dot held at 0 beyond the limits
_SRC_ROTOR = """
D1 = -a_om * O1 + be1
if (O1 >= om_hi and D1 > 0.0) or (O1 <= om_lo and D1 < 0.0):
    D1 = 0.0
D2 = -a_om * O2 + be2
if (O2 >= om_hi and D2 > 0.0) or (O2 <= om_lo and D2 < 0.0):
    D2 = 0.0
D3 = -a_om * O3 + be3
if (O3 >= om_hi and D3 > 0.0) or (O3 <= om_lo and D3 < 0.0):
    D3 = 0.0
D4 = -a_om * O4 + be4
if (O4 >= om_hi and D4 > 0.0) or (O4 <= om_lo and D4 < 0.0):
    D4 = 0.0
"""
# Eq. (6) with delta = Mix Omega and delta^2 = Mix Omega^2 (Eq. 7), J_z delta_r-dot in M_z
_SRC_FM = """
dt = 0.25 * (O1 + O2 + O3 + O4)
da = s_arm * (-O1 + O2 + O3 - O4)
de = s_arm * (O1 - O2 + O3 - O4)
dr = O1 + O2 - O3 - O4
S1 = O1 * O1
S2 = O2 * O2
S3 = O3 * O3
S4 = O4 * O4
dt2 = 0.25 * (S1 + S2 + S3 + S4)
da2 = s_arm * (-S1 + S2 + S3 - S4)
de2 = s_arm * (S1 - S2 + S3 - S4)
dr2 = S1 + S2 - S3 - S4
ddr = D1 + D2 - D3 - D4
Fx = u * (x_mu0 + x_muw * w + x_muh * dt)
Fy = v * (y_mu0 + y_muw * w + y_muh * dt)
Fz = (z_T0 * dt2 + z_mu0 * dt + z_mu * (u * u + v * v)
      + z_muw * (4.0 * w * dt - p * da - q * de))
Mx = (l_T0 * da2 + l_mu0 * da + l_muw * (w * da - 2.0 * l2 * p * dt - 0.5 * l2 * q * dr)
      + l_muh * v * dt + l_muh_mu0 * v + l_muh_muw * v * w + l_dr * u * dr)
My = (m_T0 * de2 + m_mu0 * de + m_muw * (w * de - 2.0 * l2 * q * dt - 0.5 * l2 * p * dr)
      + m_muh * u * dt + m_muh_mu0 * u + m_muh_muw * u * w + m_dr * v * dr)
Mz = (n_Q0 * dr2 + n_mu0 * dr + n_muw * (w * dr + p * de + q * da) + n_muw2 * p * q
      + n_muh * (u * da + v * de) + n_muh_muw * (u * p + v * q) + j_rot * ddr)
"""
# Eq. (3): position (3a, ZYX Euler R_IB of Eq. 2), Euler angles (2/3b), body velocity
# (3c: v x omega + g R^T e3 + F / m) and rates (3d: I^-1 (I omega x omega + M)); the rotor
# rows are D1..D4
_SRC_EQ3 = """
sf = sin(phi)
cf = cos(phi)
st = sin(th)
ct = cos(th)
sp = sin(psi)
cp = cos(psi)
sfst = sf * st
cfst = cf * st
d0 = ct * cp * u + (sfst * cp - cf * sp) * v + (cfst * cp + sf * sp) * w
d1 = ct * sp * u + (sfst * sp + cf * cp) * v + (cfst * sp - sf * cp) * w
d2 = -st * u + sf * ct * v + cf * ct * w
tt = st / ct
d3 = p + sf * tt * q + cf * tt * r
d4 = cf * q - sf * r
d5 = (sf * q + cf * r) / ct
d6 = v * r - w * q - g * st + Fx / m
d7 = w * p - u * r + g * sf * ct + Fy / m
d8 = u * q - v * p + g * cf * ct + Fz / m
h0 = I00 * p + I01 * q + I02 * r
h1 = I10 * p + I11 * q + I12 * r
h2 = I20 * p + I21 * q + I22 * r
t0 = h1 * r - h2 * q + Mx
t1 = h2 * p - h0 * r + My
t2 = h0 * q - h1 * p + Mz
d9 = Ii00 * t0 + Ii01 * t1 + Ii02 * t2
d10 = Ii10 * t0 + Ii11 * t1 + Ii12 * t2
d11 = Ii20 * t0 + Ii21 * t1 + Ii22 * t2
d12 = D1
d13 = D2
d14 = D3
d15 = D4
"""
_X16 = ("X", "Y", "Z", "phi", "th", "psi", "u", "v", "w", "p", "q", "r", "O1", "O2", "O3", "O4")


def _indent(src: str, n: int = 4) -> str:
    return "".join(" " * n + line + "\n" for line in src.strip("\n").splitlines())


def _hot_path_source() -> str:
    """Source of the factory that compiles the hot-path functions of one model."""
    fm = (
        "def _fm(u, v, w, p, q, r, O1, O2, O3, O4, D1, D2, D3, D4):\n"
        + _indent(_SRC_FM)
        + "    return (Fx, Fy, Fz), (Mx, My, Mz)\n"
    )
    rates = (
        "def _rotor_rates(O, c):\n    O1, O2, O3, O4 = O\n    c0, c1, c2, c3 = c\n"
        + _indent(_SRC_ESC)
        + _indent(_SRC_ROTOR)
        + "    return [D1, D2, D3, D4]\n"
    )
    deriv = (
        "def derivatives_list(x, c):\n    "
        + ", ".join(_X16)
        + " = x\n    c0, c1, c2, c3 = c\n"
        + _indent(_SRC_ESC)
        + _indent(_SRC_ROTOR)
        + _indent(_SRC_FM)
        + _indent(_SRC_EQ3)
        + "    return ["
        + ", ".join(f"d{i}" for i in range(16))
        + "]\n"
    )
    # rk4_step: the command is held, so Eq. (8)'s u_ESC is computed once; stage k evaluates
    # the derivative at x + a_k h k_(k-1) (positions are not needed by any derivative)
    body = "def rk4_step(x, c, h):\n    " + ", ".join(n + "_0" for n in _X16) + " = x\n"
    body += "    c0, c1, c2, c3 = c\n" + _indent(_SRC_ESC) + "    hh = 0.5 * h\n"
    for k, coef in ((1, None), (2, "hh"), (3, "hh"), (4, "h")):
        for i, n in enumerate(_X16[3:], start=3):
            body += (
                f"    {n} = {n}_0\n"
                if coef is None
                else f"    {n} = {n}_0 + {coef} * k{k - 1}_{i}\n"
            )
        stage = _SRC_ROTOR + _SRC_FM + _SRC_EQ3
        for i in range(16):
            stage = stage.replace(f"d{i} = ", f"k{k}_{i} = ")
        body += _indent(stage)
    body += (
        "    h6 = h / 6.0\n    return ["
        + ", ".join(
            f"{n}_0 + h6 * (k1_{i} + 2.0 * k2_{i} + 2.0 * k3_{i} + k4_{i})"
            for i, n in enumerate(_X16)
        )
        + "]\n"
    )
    consts = (
        list(K_NAMES)
        + ["s_arm", "l2", "j_rot", "a_om", "b_om", "om_lo", "om_hi", "g", "m"]
        + [f"{n}{i}{j}" for n in ("I", "Ii") for i in range(3) for j in range(3)]
        + [f"mi{i}{j}" for i in range(4) for j in range(4)]
    )
    return (
        "def _factory("
        + ", ".join(consts)
        + "):\n    from math import sin, cos\n"
        + _indent(fm)
        + _indent(rates)
        + _indent(deriv)
        + _indent(body)
        + "    return _fm, _rotor_rates, derivatives_list, rk4_step\n"
    )


_HOT_PATH_SOURCE = _hot_path_source()


class _Specialise(ast.NodeTransformer):
    """The hot path of one model: every parameter name becomes its value (a literal instead
    of a closure cell), then the arithmetic that the values settle is done once here:
    literal-only operations are folded (``2.0 * l2`` in ``2.0 * l2 * p * dt``: the same IEEE
    operation the interpreter would repeat every stage, so the same bits), products with a
    literal 0.0 are dropped from sums (off-diagonal inertia, zero aerodynamic coefficients:
    ``x + 0.0 * y`` is ``x`` for finite y) and products with 1.0 are bypassed. The default
    model loses ~24 % of its float operations this way; the order of every operation that
    remains is unchanged, so results agree bit for bit with the unspecialised source (up to
    the sign of a zero)."""

    def __init__(self, consts: Mapping[str, float]) -> None:
        self.consts = consts

    def visit_Name(self, node: ast.Name) -> ast.AST:
        if isinstance(node.ctx, ast.Load) and node.id in self.consts:
            return ast.copy_location(ast.Constant(float(self.consts[node.id])), node)
        return node

    def visit_UnaryOp(self, node: ast.UnaryOp) -> ast.AST:
        self.generic_visit(node)
        v = _num(node.operand)
        if isinstance(node.op, ast.USub) and v is not None:
            return ast.copy_location(ast.Constant(-v), node)
        return node

    def visit_BinOp(self, node: ast.BinOp) -> ast.AST:
        self.generic_visit(node)
        a, b, op = node.left, node.right, node.op
        va, vb = _num(a), _num(b)
        if va is not None and vb is not None:
            if isinstance(op, ast.Add):
                return ast.copy_location(ast.Constant(va + vb), node)
            if isinstance(op, ast.Sub):
                return ast.copy_location(ast.Constant(va - vb), node)
            if isinstance(op, ast.Mult):
                return ast.copy_location(ast.Constant(va * vb), node)
        if isinstance(op, ast.Mult):
            if va == 0.0 or vb == 0.0:
                return ast.copy_location(ast.Constant(0.0), node)
            if va == 1.0:
                return b
            if vb == 1.0:
                return a
        if isinstance(op, (ast.Add, ast.Sub)) and vb == 0.0:
            return a
        if isinstance(op, ast.Add) and va == 0.0:
            return b
        if isinstance(op, ast.Sub) and va == 0.0:
            return ast.copy_location(ast.UnaryOp(ast.USub(), b), node)
        return node


def _num(node: ast.AST) -> float | None:
    """The value of a float literal node, else None."""
    if isinstance(node, ast.Constant) and type(node.value) is float:
        return node.value
    return None


@functools.lru_cache(maxsize=64)
def _hot_path_code(consts: tuple) -> Any:
    """The hot-path factory compiled for one model's parameters ``consts`` (sorted items)."""
    tree = _Specialise(dict(consts)).visit(ast.parse(_HOT_PATH_SOURCE))
    return compile(
        ast.fix_missing_locations(tree), "<lpv_sysid.models.quadrotor hot path>", "exec"
    )


def hot_path_constants(
    p: QuadrotorParams, mix_inv: np.ndarray, inertia_inv: np.ndarray
) -> dict[str, float]:
    """The parameter values the hot path of a model is specialised on (name -> value)."""
    ell = p.arm_length
    consts = dict(zip(K_NAMES, (p.K[k] for k in K_NAMES)))
    consts.update(
        s_arm=ell * HALF_SQRT2,
        l2=ell * ell,
        j_rot=p.j_rotor,
        a_om=p.a_omega,
        b_om=p.b_omega,
        om_lo=p.omega_min,
        om_hi=p.omega_max,
        g=p.g,
        m=p.mass,
    )
    for i in range(3):
        for j in range(3):
            consts[f"I{i}{j}"] = p.inertia[i][j]
            consts[f"Ii{i}{j}"] = float(inertia_inv[i][j])
    for i in range(4):
        for j in range(4):
            consts[f"mi{i}{j}"] = float(mix_inv[i][j])
    return {k: float(v) for k, v in consts.items()}


def compile_hot_path(constants: Mapping[str, float]) -> tuple[Any, Any, Any, Any]:
    """``(_fm, _rotor_rates, derivatives_list, rk4_step)`` compiled for ``constants``
    (:func:`hot_path_constants`); the code is cached per parameter set."""
    ns: dict = {}
    code = _hot_path_code(tuple(sorted(constants.items())))
    exec(code, ns)  # noqa: S102 - compiled from this module's own source text
    return ns["_factory"](**constants)
