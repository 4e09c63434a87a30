"""Compiled joint loops: the angle changes and Hessian blocks of the rotational springs (numba).

The springs of :mod:`espin.mechanics.bending` (fiber joints, and the fused crossings of
:mod:`espin.mechanics.crossings` appended to them) are evaluated joint by joint here, compiled
by numba with IEEE semantics (no fast-math) and the GIL released, with the formulas of the
bending module's notes. At plla size with every crossing fused (about 2e5 joints) the numpy
formulation they replace built a dozen (n_joints, 6, 6) temporaries per tangent and took
longer than the tangent's factorization; here a joint's 36 entries are written once.

Compiled code is cached on disk next to this module (numba's ``cache=True``), like
:mod:`espin.mechanics.kernels`. Units: positions and lengths um, angles rad, stiffnesses
uN um, Hessian entries uN / um.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["geometry", "blocks"]

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def _joint(x: np.ndarray, a: int, b: int, c: int, floor_u: float, floor_v: float, reference: float):
    """(active, change, ux, uy, vx, vy, uu, vv) of one joint a -> b -> c; an inactive joint
    (an element at or below its floor) has change 0 and u = v = (1, 0)."""
    ux, uy = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1]
    vx, vy = x[c, 0] - x[b, 0], x[c, 1] - x[b, 1]
    uu, vv = ux * ux + uy * uy, vx * vx + vy * vy
    if not (uu > floor_u * floor_u and vv > floor_v * floor_v):
        return False, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 1.0
    theta = math.atan2(ux * vy - uy * vx, ux * vx + uy * vy)
    change = (theta - reference + math.pi) % (2.0 * math.pi) - math.pi
    return True, change, ux, uy, vx, vy, uu, vv


@_jit
def geometry(
    x: np.ndarray, nodes: np.ndarray, floor: np.ndarray, reference: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Angle change, d theta / d(x_a, x_b, x_c) and |u|^2, |v|^2 of every joint.

    Parameters
    ----------
    x : (n_nodes, 2) float64 [um]
        Node positions.
    nodes : (n_joints, 3) int64
        Nodes (a, b, c) of each joint.
    floor : (n_joints, 2) float64 [um]
        Length floor of the elements a-b and b-c.
    reference : (n_joints,) float64 [rad]
        theta_0.

    Returns
    -------
    change : (n_joints,) float64 [rad]
        theta - theta_0 wrapped to [-pi, pi); 0 for an inactive joint.
    jacobian : (n_joints, 6) float64 [1/um]
        (perp(u)/|u|^2, -perp(u)/|u|^2 - perp(v)/|v|^2, perp(v)/|v|^2); 0 for an inactive joint.
    uu, vv : (n_joints,) float64 [um^2]
        |u|^2 and |v|^2 (1 for an inactive joint).
    """
    n = len(nodes)
    change = np.zeros(n)
    jacobian = np.zeros((n, 6))
    uu_out, vv_out = np.ones(n), np.ones(n)
    for j in range(n):
        active, d, ux, uy, vx, vy, uu, vv = _joint(
            x, nodes[j, 0], nodes[j, 1], nodes[j, 2], floor[j, 0], floor[j, 1], reference[j]
        )
        if not active:
            continue
        change[j], uu_out[j], vv_out[j] = d, uu, vv
        dux, duy, dvx, dvy = -uy / uu, ux / uu, -vy / vv, vx / vv
        jacobian[j, 0], jacobian[j, 1] = dux, duy
        jacobian[j, 2], jacobian[j, 3] = -dux - dvx, -duy - dvy
        jacobian[j, 4], jacobian[j, 5] = dvx, dvy
    return change, jacobian, uu_out, vv_out


@_jit
def blocks(
    x: np.ndarray, nodes: np.ndarray, floor: np.ndarray, reference: np.ndarray, stiffness: np.ndarray, exact: bool
) -> np.ndarray:
    """(n_joints, 6, 6) Hessian of each joint's energy k (1 - cos(theta - theta_0)) [uN / um].

    k cos(Delta) J J^T + k sin(Delta) d^2 theta / dx^2 (J = d theta / dx); ``exact`` False
    keeps k max(cos(Delta), 0) J J^T only (positive semi-definite). Zero for an inactive joint.
    Arguments as :func:`geometry`, with ``stiffness`` k (n_joints,) [uN um].
    """
    n = len(nodes)
    out = np.zeros((n, 6, 6))
    jac = np.empty(6)
    hu = np.empty((2, 2))
    hv = np.empty((2, 2))
    for j in range(n):
        active, d, ux, uy, vx, vy, uu, vv = _joint(
            x, nodes[j, 0], nodes[j, 1], nodes[j, 2], floor[j, 0], floor[j, 1], reference[j]
        )
        if not active:
            continue
        k = stiffness[j]
        cosine = math.cos(d) if exact else max(math.cos(d), 0.0)
        dux, duy, dvx, dvy = -uy / uu, ux / uu, -vy / vv, vx / vv
        jac[0], jac[1], jac[2], jac[3], jac[4], jac[5] = dux, duy, -dux - dvx, -duy - dvy, dvx, dvy
        for r in range(6):
            for s in range(6):
                out[j, r, s] = k * cosine * jac[r] * jac[s]
        if exact:
            # d(perp(w) / |w|^2) / dw = R / |w|^2 - 2 perp(w) w^T / |w|^4 (symmetric), w = u and v.
            ks = k * math.sin(d)
            _perp_derivative(ux, uy, uu, hu)
            _perp_derivative(vx, vy, vv, hv)
            for r in range(2):
                for s in range(2):
                    out[j, r, s] -= ks * hu[r, s]
                    out[j, r, 2 + s] += ks * hu[r, s]
                    out[j, 2 + r, s] += ks * hu[r, s]
                    out[j, 2 + r, 2 + s] += ks * (hv[r, s] - hu[r, s])
                    out[j, 2 + r, 4 + s] -= ks * hv[r, s]
                    out[j, 4 + r, 2 + s] -= ks * hv[r, s]
                    out[j, 4 + r, 4 + s] += ks * hv[r, s]
    return out


@_jit
def _perp_derivative(wx: float, wy: float, ww: float, out: np.ndarray) -> None:
    """``out`` (2, 2) = d(perp(w) / |w|^2) / dw, perp(w) = (-w_y, w_x)."""
    w4 = ww * ww
    out[0, 0] = 2.0 * wx * wy / w4
    out[0, 1] = -1.0 / ww + 2.0 * wy * wy / w4
    out[1, 0] = 1.0 / ww - 2.0 * wx * wx / w4
    out[1, 1] = -2.0 * wx * wy / w4
