"""``LinearContainerFactor``: a Gaussian prior on variables, kept with its linearization point.

Marginalizing variables out of a linearized system leaves, on the remaining ones (their Markov
blanket), the quadratic ``0.5 dx^T H dx + g^T dx + const`` in the tangent coordinates
``dx = local(x0, x)`` of the blanket at its linearization point ``x0`` (GTSAM's
``LinearContainerFactor``). As a factor: with ``H = R^T R`` (``R`` upper triangular) and
``b = R^-T g``, the residual

    e(x) = R local(x0, x) + b,       0.5 |e|^2 = 0.5 dx^T H dx + g^T dx + 0.5 g^T H^-1 g

reproduces it exactly at ``x0`` and anywhere else; its Jacobian ``R d local(x0, x) / dx`` is
``R`` at ``x0`` (central differences of the manifold's ``local`` elsewhere, so the factor is
exact on any manifold, where GTSAM's keeps ``R``).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..errors import DimensionMismatchError, NotPositiveDefiniteError
from ..factors.base import Factor
from ..key import key_str
from ..manifolds.base import ops_for


def _upper_sqrt(H: np.ndarray) -> np.ndarray:
    """Upper-triangular ``R`` with ``R^T R = H`` (eigenvalues clipped at a relative 1e-12
    when rounding left ``H`` semidefinite)."""
    try:
        return np.linalg.cholesky(H).T
    except np.linalg.LinAlgError:
        w, Q = np.linalg.eigh(0.5 * (H + H.T))
        if w[-1] <= 0:
            raise NotPositiveDefiniteError("LinearContainerFactor: the information matrix has "
                                           "no positive eigenvalue") from None
        w = np.maximum(w, 1e-12 * w[-1])
        return np.linalg.cholesky((Q * w) @ Q.T).T


class LinearContainerFactor(Factor):
    """``LinearContainerFactor(keys, linearization_point, information, gradient)``.

    Args:
        keys: the blanket's keys, in the order of the rows of ``information``.
        linearization_point: their values ``x0`` (a sequence, or anything with ``.at(key)``).
        information: ``H``, ``(n, n)`` symmetric positive definite (``n`` = sum of the keys'
            tangent dims, rotation first as every fgopt tangent).
        gradient: ``g``, ``(n,)``: the cost's gradient at ``x0``.

    Example: on R^2 the quadratic's minimum is ``x0 - H^-1 g``:

    >>> from fgopt.incremental import LinearContainerFactor
    >>> x0 = fgopt.Variables().add(key('p', 0), np.array([1.0, 2.0]))
    >>> f = LinearContainerFactor([key('p', 0)], x0, np.diag([4.0, 1.0]), np.array([4.0, -1.0]))
    >>> x = fgopt.Variables().add(key('p', 0), np.array([1.5, 1.0]))
    >>> 0.5 * float(f.error(x) @ f.error(x))   # 0.5 dx'H dx + g'dx + 0.5 g'H^-1 g = 1 + 3 + 2.5
    6.5
    >>> np.round(fgopt.optimize(fgopt.FactorGraph([f]), x).values.at(key('p', 0)), 6)
    array([0., 3.])
    """

    #: central-difference step for the Jacobian of ``local`` away from ``x0``
    delta: float = 1e-6

    def __init__(self, keys: Sequence[int], linearization_point: Any, information: np.ndarray,
                 gradient: np.ndarray):
        keys = list(keys)
        if hasattr(linearization_point, "at"):
            x0 = [linearization_point.at(k) for k in keys]
        else:
            x0 = list(linearization_point)
        dims = [ops_for(v).dim(v) for v in x0]
        n = int(sum(dims))
        H = np.array(information, dtype=float)
        g = np.array(gradient, dtype=float).reshape(-1)
        if H.shape != (n, n) or g.shape != (n,):
            raise DimensionMismatchError(
                f"LinearContainerFactor: information {H.shape} / gradient {g.shape} do not match "
                f"the keys' tangent dim {n}")
        self.linearization_point = x0
        self.information = 0.5 * (H + H.T)
        self.gradient = g
        self._R = _upper_sqrt(self.information)
        self._b = np.linalg.solve(self._R.T, g)
        self._offsets = np.concatenate([[0], np.cumsum(dims)]).astype(int)
        super().__init__(keys, n, None)

    def local(self, values: Any) -> np.ndarray:
        """``dx = local(x0, x)`` of every key, stacked."""
        return np.concatenate([ops_for(x0).local(x0, values.at(k))
                               for k, x0 in zip(self.keys, self.linearization_point)])

    def error(self, values: Any) -> np.ndarray:
        return self._R @ self.local(values) + self._b

    def jacobians(self, values: Any) -> list[np.ndarray]:
        out = []
        for i, (k, x0) in enumerate(zip(self.keys, self.linearization_point)):
            R_k = self._R[:, self._offsets[i]:self._offsets[i + 1]]
            x = values.at(k)
            ops = ops_for(x)
            d = ops.dim(x)
            d0 = ops.local(x0, x)
            if not np.any(d0):
                out.append(R_k.copy())        # d local(x0, x0 (+) t) / dt = I at t = 0
                continue
            D = np.empty((d, d))
            for j in range(d):
                step = np.zeros(d)
                step[j] = self.delta
                D[:, j] = (ops.local(x0, ops.retract(x, step)) -
                           ops.local(x0, ops.retract(x, -step))) / (2 * self.delta)
            out.append(R_k @ D)
        return out

    def describe(self) -> str:
        return f"LinearContainerFactor({', '.join(key_str(k) for k in self.keys)})"
