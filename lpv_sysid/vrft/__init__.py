"""MIMO Virtual Reference Feedback Tuning (seed 1, Sec. 3.3, Eqs. 3.7-3.31).

Given one input/output record ``u`` (N x n_u), ``y`` (N x n_y) of an unknown LTI plant, a
reference model ``M(z)`` (n_y x n_y matrix of discrete transfer functions) and a controller
class linear in its parameters ``C(z; theta) = sum_q K_q beta_q(z)`` (seed 1 Assumption 2), find
``theta`` such that the virtual closed loop reproduces the data:

* virtual reference ``r_v = M^-1 y`` (Eq. 3.7), virtual error ``e_v = r_v - y`` (Eq. 3.8);
* filtered signals ``u_L = L u``, ``e_L = L e_v`` (Eqs. 3.10-3.11) with the thesis choice
  ``L = M`` (Eq. 3.18) so that ``e_L = (I - M) y`` never needs ``M^-1`` (Sec. 3.3.4 steps 1-2);
* least squares ``min 1/N sum ||u_L(k) - phi_L^T(k) theta||^2`` (Eqs. 3.13-3.14) with the
  Kronecker regressor ``phi^T(k) = [(beta_1 e_L)(k)^T (x) I, ..., (beta_p e_L)(k)^T (x) I]``
  and ``theta = vec([K_1, ..., K_p])`` (Eqs. 3.21-3.24; the velocity basis
  ``beta_i = z/(z-1) z^-i`` is exactly Eqs. 3.19-3.25);
* extended instrumental variables for noisy data (Eqs. 3.26-3.31):
  ``zeta_L(k) = [u_L(k+l); ...; u_L(k-l)]``, ``R = 1/N sum zeta_L (x) phi_L^T``,
  ``r = 1/N sum zeta_L (x) u_L``, ``theta = (R^T W^-1 R)^-1 R^T W^-1 r`` (W = I as in step 5
  of the Sec. 3.3.4 pseudo-code); or the classic second-experiment / model-based instrument
  of Sec. 3.3.2 (``phi`` rebuilt from a second output record ``y2`` with the same input).

Filtering with a *matrix* ``M`` would not commute with ``C(theta)``, so for a non-scalar
reference model the common scalar filter is ``L = det M`` and ``L M^-1 = adj M`` (proper and
stable when ``M`` is); for ``M = m(z) I`` this reduces to the thesis' ``L = m`` exactly.
An optional extra scalar pre-filter ``W(z)`` multiplies both sides (e.g. ``1 - m``, which gives
the SISO filter ``L = (1 - M) M`` of Eq. 3.12 for a flat input spectrum).

Transfer functions are ``(num, den)`` in descending powers of ``z`` (scipy.signal.dlti
convention) and are applied with ``scipy.signal.lfilter`` from rest.

Parts (one job each):

- :mod:`~lpv_sysid.vrft.tf`: ``Tf``, reference models (``first_order_model``,
  ``diagonal_model``), determinant / adjugate of ``M``;
- :mod:`~lpv_sysid.vrft.controller_class`: ``ControllerClass``, ``pid_class``, ``velocity_class``;
- :mod:`~lpv_sysid.vrft.controller`: ``VrftResult``, ``controller_tf``,
  ``invert_controller``, ``model_reference_h2``, ``simulate_loop``.
"""

from __future__ import annotations

from lpv_sysid.vrft.cascade import cascaded_vrft
from lpv_sysid.vrft.config import VrftConfig
from lpv_sysid.vrft.controller import (
    VrftResult,
    controller_tf,
    invert_controller,
    model_reference_h2,
)
from lpv_sysid.vrft.controller_class import pid_class, velocity_class
from lpv_sysid.vrft.runs import LV100_CONFIG, TABLE53_CONFIG, TuneResult, load_data, tune
from lpv_sysid.vrft.tf import Tf, diagonal_model, first_order_model
from lpv_sysid.vrft.tuning import vrft

__all__ = [
    "LV100_CONFIG",
    "TABLE53_CONFIG",
    "Tf",
    "TuneResult",
    "VrftConfig",
    "VrftResult",
    "cascaded_vrft",
    "controller_tf",
    "diagonal_model",
    "first_order_model",
    "invert_controller",
    "load_data",
    "model_reference_h2",
    "pid_class",
    "tune",
    "velocity_class",
    "vrft",
]
