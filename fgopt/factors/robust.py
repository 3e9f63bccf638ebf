"""Robust loss evaluation shared by Python and numba code.

``rho_and_weight(code, k, s)`` takes the squared whitened norm ``s = t^2`` and returns the loss
``rho(t)`` and the IRLS weight ``w = rho'(t)/t`` (so ``w = 1`` and ``rho = s/2`` for no loss).
"""

from __future__ import annotations

import math

import numba


@numba.njit(cache=True)
def rho_and_weight(code, k, s):
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
    return 0.5 * s, 1.0
