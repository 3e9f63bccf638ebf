"""Sim(3) kernels: storage [q(4), t(3), s], tangent [w(3), v(3), lambda], s = exp(lambda) (Eade).

Part of :mod:`fgopt.manifolds._kernels` (conventions in its docstring).
"""

from __future__ import annotations

import math

import numpy as np
from ..._jit import njit

from ._common import fill_block, invert, jr_from_ad, skew_poly_apply
from .so3 import quat_rotate, so3_compose, so3_exp, so3_log
from .se3 import _se3_adjoint_scaled, se3_ad, se3_inverse


@njit(cache=True)
def _moment(k, lam):
    """int_0^1 s^k e^(s lam) ds."""
    if abs(lam) < 0.5:
        acc, term = 0.0, 1.0
        for j in range(30):
            acc += term / (k + j + 1)
            term *= lam / (j + 1)
        return acc
    m = math.expm1(lam) / lam
    el = math.exp(lam)
    for i in range(1, k + 1):
        m = (el - i * m) / lam
    return m


@njit(cache=True)
def sim3_w_coeffs(t2, lam):
    """(a0, a1, a2) with W(w, lam) = int_0^1 e^(s lam) Exp(s w) ds = a0 I + a1 W + a2 W^2.

    a0 = (e^lam - 1)/lam; with Q = (e^z - 1)/z, z = lam + i t: a1 = Im Q / t,
    a2 = (a0 - Re Q)/t^2; below t = 1e-3, series in t with moments of e^(s lam).
    """
    if abs(lam) < 1e-5:
        a0 = 1.0 + lam * (0.5 + lam * (1.0 / 6.0 + lam / 24.0))
    else:
        a0 = math.expm1(lam) / lam
    if t2 < 1e-6:
        a1 = _moment(1, lam) - t2 * _moment(3, lam) / 6.0 + t2 * t2 * _moment(5, lam) / 120.0
        a2 = _moment(2, lam) / 2.0 - t2 * _moment(4, lam) / 24.0 + t2 * t2 * _moment(6, lam) / 720.0
        return a0, a1, a2
    t = math.sqrt(t2)
    sh = math.sin(0.5 * t)
    p_re = math.expm1(lam) * math.cos(t) - 2.0 * sh * sh  # e^z - 1
    p_im = math.exp(lam) * math.sin(t)
    den = lam * lam + t2
    q_re = (p_re * lam + p_im * t) / den
    q_im = (p_im * lam - p_re * t) / den
    return a0, q_im / t, (a0 - q_re) / t2


@njit(cache=True)
def sim3_compose(a, b, out):
    so3_compose(a, b, out)
    quat_rotate(a, b[4:7], out[4:7])
    for i in range(4, 7):
        out[i] = a[7] * out[i] + a[i]
    out[7] = a[7] * b[7]


@njit(cache=True)
def sim3_inverse(a, out):
    se3_inverse(a, out)
    inv_s = 1.0 / a[7]
    for i in range(4, 7):
        out[i] *= inv_s
    out[7] = inv_s


@njit(cache=True)
def sim3_exp(xi, out):
    so3_exp(xi, out)
    a0, a1, a2 = sim3_w_coeffs(xi[0] * xi[0] + xi[1] * xi[1] + xi[2] * xi[2], xi[6])
    skew_poly_apply(xi, a0, a1, a2, xi[3:6], out[4:7])
    out[7] = math.exp(xi[6])


@njit(cache=True)
def sim3_log(x, out):
    """Log via W^-1 = b0 I + b1 W + b2 W^2: b0 = 1/a0, b1 = -a1/D, b2 = (a1^2 - a2 u)/(a0 D),
    u = a0 - a2 t^2, D = u^2 + a1^2 t^2 (W has eigenvalues 0, +-i t)."""
    so3_log(x, out)
    lam = math.log(x[7])
    t2 = out[0] * out[0] + out[1] * out[1] + out[2] * out[2]
    a0, a1, a2 = sim3_w_coeffs(t2, lam)
    u = a0 - a2 * t2
    d = u * u + a1 * a1 * t2
    skew_poly_apply(out, 1.0 / a0, -a1 / d, (a1 * a1 - a2 * u) / (a0 * d), x[4:7], out[3:6])
    out[6] = lam


@njit(cache=True)
def sim3_adjoint(x, out):
    """Adj = [[R, 0, 0], [hat(t) R, s R, -t], [0, 0, 1]]."""
    _se3_adjoint_scaled(x, out, x[7])
    fill_block(out, 0, 6, 6, 1, 0.0)
    fill_block(out, 6, 0, 1, 6, 0.0)
    for i in range(3):
        out[3 + i, 6] = -x[4 + i]
    out[6, 6] = 1.0


@njit(cache=True)
def sim3_ad(xi, out):
    """ad = [[W, 0, 0], [hat(v), W + lam I, -v], [0, 0, 0]]."""
    se3_ad(xi, out)
    fill_block(out, 0, 6, 3, 1, 0.0)
    fill_block(out, 6, 0, 1, 7, 0.0)
    for i in range(3):
        out[3 + i, 3 + i] = xi[6]
        out[3 + i, 6] = -xi[3 + i]


@njit(cache=True)
def sim3_jr(xi, out):
    ad = np.empty((7, 7))
    sim3_ad(xi, ad)
    jr_from_ad(ad, out)


@njit(cache=True)
def sim3_jrinv(xi, out):
    jr = np.empty((7, 7))
    sim3_jr(xi, jr)
    invert(jr, out)
