"""Robust loss evaluation shared by Python and numba code.

``rho_and_weight(code, k, shape, s)`` takes the squared whitened norm ``s = t^2`` and returns the
loss ``rho(t)`` and the IRLS weight ``w = rho'(t)/t`` (so ``w = 1`` and ``rho = s/2`` for no
loss). ``k`` is the loss's scale; ``shape`` is used by Barron's loss only (its ``alpha``).

Barron's general adaptive loss (Barron, CVPR 2019), scaled so that ``rho ~ t^2/2`` near 0 like
the others::

    rho(t) = k^2 |a - 2| / a * ((t^2 / (k^2 |a - 2|) + 1)^(a/2) - 1)

It is L2 at ``a = 2``, pseudo-Huber at 1, Cauchy (with ``2 k^2``) at 0, Geman-McClure at -2 and
Welsch as ``a -> -inf``; the formula is 0/0 at ``a = 0`` and ``a = 2``. As in SymForce (paper,
Sec. VI), the singular points are removed branch-free with a small ``epsilon``:
``b = |a - 2| + eps`` and ``d = a + eps sign_no_zero(a)`` replace ``|a - 2|`` and ``a``, giving
``rho = k^2 b/d ((s/(k^2 b) + 1)^(d/2) - 1)`` and ``w = (s/(k^2 b) + 1)^(d/2 - 1)``. The power
minus one is evaluated as ``expm1(d/2 * log1p(.))`` so the ``1/d`` factor does not amplify
rounding when ``d`` is tiny (``a = 0``). ``tests/core/test_noise.py`` checks the limits with
:func:`fgopt.symbolic.check_removable_singularity`.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import njit

#: SymForce's default epsilon (10 machine epsilons), as in :mod:`fgopt.symbolic`.
BARRON_EPSILON = 2.220446049250313e-15


@njit(cache=True)
def barron(k, alpha, s):
    """Barron's loss and IRLS weight at ``s = t^2`` (epsilon-safe at ``alpha`` = 0 and 2)."""
    eps = BARRON_EPSILON
    b = abs(alpha - 2.0) + eps
    d = alpha + (eps if alpha >= 0.0 else -eps)
    k2 = k * k
    lu = math.log1p(s / (k2 * b))
    return k2 * b / d * math.expm1(0.5 * d * lu), math.exp((0.5 * d - 1.0) * lu)


@njit(cache=True)
def rho_and_weight(code, k, shape, s):
    if code == 0:
        return 0.5 * s, 1.0
    k2 = k * k
    if code == 1:  # Huber
        t = math.sqrt(s)
        if t <= k:
            return 0.5 * s, 1.0
        return k * t - 0.5 * k2, k / t
    if code == 2:  # Cauchy
        return 0.5 * k2 * math.log1p(s / k2), 1.0 / (1.0 + s / k2)
    if code == 3:  # Tukey
        if s <= k2:
            u = 1.0 - s / k2
            return k2 / 6.0 * (1.0 - u * u * u), u * u
        return k2 / 6.0, 0.0
    if code == 4:  # Geman-McClure
        d = k2 + s
        return 0.5 * k2 * s / d, k2 * k2 / (d * d)
    if code == 5:  # Barron
        return barron(k, shape, s)
    return 0.5 * s, 1.0


def rho_and_weight_np(code: int, k: float, shape: float, s: np.ndarray):
    """:func:`rho_and_weight` over an array of squared norms ``s`` (NumPy; small batches)."""
    s = np.asarray(s, dtype=float)
    with np.errstate(all="ignore"):
        if code == 0 or code not in (1, 2, 3, 4, 5):
            return 0.5 * s, np.ones_like(s)
        k2 = k * k
        if code == 1:  # Huber
            t = np.sqrt(s)
            inside = t <= k
            return (np.where(inside, 0.5 * s, k * t - 0.5 * k2),
                    np.where(inside, 1.0, k / np.where(inside, 1.0, t)))
        if code == 2:  # Cauchy
            return 0.5 * k2 * np.log1p(s / k2), 1.0 / (1.0 + s / k2)
        if code == 3:  # Tukey
            u = 1.0 - s / k2
            inside = s <= k2
            return (np.where(inside, k2 / 6.0 * (1.0 - u * u * u), k2 / 6.0),
                    np.where(inside, u * u, 0.0))
        if code == 4:  # Geman-McClure
            d = k2 + s
            return 0.5 * k2 * s / d, k2 * k2 / (d * d)
        eps = BARRON_EPSILON
        b = abs(shape - 2.0) + eps
        d = shape + (eps if shape >= 0.0 else -eps)
        lu = np.log1p(s / (k2 * b))
        return k2 * b / d * np.expm1(0.5 * d * lu), np.exp((0.5 * d - 1.0) * lu)
