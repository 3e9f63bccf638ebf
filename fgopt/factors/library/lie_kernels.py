"""Batched Between and Prior factor kernels for the Lie groups and vector spaces.

Residuals (GTSAM's definitions), with ``m`` the measurement stored in the constants row::

    between(a, b; m) = Log(m^-1 * (a^-1 * b))        vectors: (b - a) - m
    prior(x; m)      = Log(m^-1 * x)                  vectors: x - m

Jacobians are exact with respect to right perturbations ``x * Exp(d)`` (the groups' retract).
With ``E = m^-1 a^-1 b`` and ``e = Log(E)``:

* perturbing ``b``: ``E Exp(d)``, so ``de/db = Jr^-1(e)``;
* perturbing ``a``: ``(a Exp(d))^-1 = Exp(-d) a^-1`` and
  ``m^-1 Exp(-d) a^-1 b = E Exp(-Adj((a^-1 b)^-1) d)``, so ``de/da = -Jr^-1(e) Adj(b^-1 a)``;
* prior: ``de/dx = Jr^-1(e)``.

``Jr^-1`` is closed-form for SO(2), SE(2), SO(3), SE(3) and computed to rounding error from
``phi(-ad)`` for Sim(3) (see :mod:`fgopt.manifolds._kernels`). Kernels are cached: one object per
batch kind, so factors of one kind batch together.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from ..._jit import njit, specialize

from ...errors import DimensionMismatchError, ManifoldError
from ...manifolds._kernels import (
    MAX_STORAGE_DIM,
    lie_adjoint,
    lie_compose,
    lie_inverse,
    lie_jrinv,
    lie_log,
    tangent_dim,
)
from ...manifolds.base import SCALAR_KIND, BatchKind, vector_kind
from ...manifolds.lie import group_id
from ..kernel import CompiledCall, FactorKernel

_SOURCE = "hand-written in fgopt/factors/library/lie_kernels.py"


@njit(cache=True)
def _jac_block(jac_i, col, sign, jri, adj, d):
    """jac_i[:, col:col+d] = sign * jri @ adj."""
    for r in range(d):
        for c in range(d):
            acc = 0.0
            for k in range(d):
                acc += jri[r, k] * adj[k, c]
            jac_i[r, col + c] = sign * acc


@njit(cache=True, inline="always")  # specialize()d per group
def lie_between_batch(gid, a, b, m, with_jac):
    """Residuals ``(n, d)`` and, if ``with_jac``, Jacobians ``(n, d, 2d)`` of Log(m^-1 a^-1 b)."""
    n = a.shape[0]
    d = tangent_dim(gid)
    res = np.empty((n, d))
    jac = np.empty((n if with_jac else 0, d, 2 * d))
    ainv = np.empty(MAX_STORAGE_DIM)
    ab = np.empty(MAX_STORAGE_DIM)
    minv = np.empty(MAX_STORAGE_DIM)
    err = np.empty(MAX_STORAGE_DIM)
    ba = np.empty(MAX_STORAGE_DIM)
    jri = np.empty((d, d))
    adj = np.empty((d, d))
    eye = np.eye(d)
    for i in range(n):
        lie_inverse(gid, a[i], ainv)
        lie_compose(gid, ainv, b[i], ab)
        lie_inverse(gid, m[i], minv)
        lie_compose(gid, minv, ab, err)
        lie_log(gid, err, res[i])
        if with_jac:
            lie_jrinv(gid, res[i], jri)
            lie_inverse(gid, ab, ba)
            lie_adjoint(gid, ba, adj)
            _jac_block(jac[i], 0, -1.0, jri, adj, d)
            _jac_block(jac[i], d, 1.0, jri, eye, d)
    return res, jac


@njit(cache=True, inline="always")  # specialize()d per group
def lie_prior_batch(gid, x, m, with_jac):
    """Residuals ``(n, d)`` and, if ``with_jac``, Jacobians ``(n, d, d)`` of Log(m^-1 x)."""
    n = x.shape[0]
    d = tangent_dim(gid)
    res = np.empty((n, d))
    jac = np.empty((n if with_jac else 0, d, d))
    minv = np.empty(MAX_STORAGE_DIM)
    err = np.empty(MAX_STORAGE_DIM)
    for i in range(n):
        lie_inverse(gid, m[i], minv)
        lie_compose(gid, minv, x[i], err)
        lie_log(gid, err, res[i])
        if with_jac:
            lie_jrinv(gid, res[i], jac[i])
    return res, jac


@njit(cache=True)
def vector_between_batch(a, b, m, with_jac):
    """Residuals ``(b - a) - m`` and Jacobians ``[-I, I]``."""
    n, d = a.shape
    res = (b - a) - m
    jac = np.zeros((n if with_jac else 0, d, 2 * d))
    for i in range(jac.shape[0]):
        for r in range(d):
            jac[i, r, r] = -1.0
            jac[i, r, d + r] = 1.0
    return res, jac


@njit(cache=True)
def vector_prior_batch(x, m, with_jac):
    """Residuals ``x - m`` and Jacobians ``I``."""
    n, d = x.shape
    res = x - m
    jac = np.zeros((n if with_jac else 0, d, d))
    for i in range(jac.shape[0]):
        for r in range(d):
            jac[i, r, r] = 1.0
    return res, jac


def _prepared(name: str, kind: BatchKind, nargs: int, args: tuple, consts: np.ndarray):
    """Check shapes; return float64 C-contiguous arrays (no copies when already so)."""
    if len(args) != nargs:
        raise DimensionMismatchError(f"{name}: expected {nargs} argument arrays, got {len(args)}")
    arrs = [np.ascontiguousarray(x, dtype=np.float64) for x in args]
    c = np.ascontiguousarray(consts, dtype=np.float64)
    n = c.shape[0] if c.ndim == 2 else -1
    for x in arrs:
        if x.ndim != 2 or x.shape != (n, kind.storage_dim):
            raise DimensionMismatchError(
                f"{name}: argument arrays must be (n, {kind.storage_dim}) and constants "
                f"(n, {kind.storage_dim}); got {x.shape} and {c.shape}")
    if c.ndim != 2 or c.shape[1] != kind.storage_dim:
        raise DimensionMismatchError(
            f"{name}: constants must be (n, {kind.storage_dim}), got {c.shape}")
    return arrs, c


def _is_vector_kind(kind: BatchKind) -> bool:
    return kind is SCALAR_KIND or (kind.name.startswith("R") and kind is vector_kind(kind.dim))


def _unsupported(which: str, kind: BatchKind) -> ManifoldError:
    return ManifoldError(
        f"{which}: no built-in kernel for batch kind {kind.name!r}; supported are SO2, SE2, SO3, "
        "SE3, Sim3 and vector kinds (write a custom factor for other manifolds)")


@cache
def between_kernel(kind: BatchKind) -> FactorKernel:
    """The Between kernel of ``kind``: args ``(a, b)``, constants = storage of ``m``."""
    name = f"between_{kind.name.lower()}"
    gid = group_id(kind)
    if gid is not None:
        batch = specialize(lie_between_batch, gid)

        def run(args, consts, with_jac):
            (a, b), c = _prepared(name, kind, 2, args, consts)
            return batch(a, b, c, with_jac)

        def trusted(args, consts):
            return batch(args[0], args[1], consts, True)
        call = CompiledCall(__name__, "lie_between_batch", prefix=f"{gid}, ", suffix=", True")
    elif _is_vector_kind(kind):
        def run(args, consts, with_jac):
            (a, b), c = _prepared(name, kind, 2, args, consts)
            return vector_between_batch(a, b, c, with_jac)

        def trusted(args, consts):
            return vector_between_batch(args[0], args[1], consts, True)
        call = CompiledCall(__name__, "vector_between_batch", suffix=", True")
    else:
        raise _unsupported("between_kernel", kind)
    return FactorKernel(name, (kind, kind), kind.dim, kind.storage_dim,
                        residual=lambda args, consts: run(args, consts, False)[0],
                        linearize=lambda args, consts: run(args, consts, True),
                        source=_SOURCE, recipe=(between_kernel, (kind,)),
                        trusted_linearize=trusted, compiled_call=call)


@cache
def prior_kernel(kind: BatchKind) -> FactorKernel:
    """The Prior kernel of ``kind``: arg ``(x,)``, constants = storage of ``m``."""
    name = f"prior_{kind.name.lower()}"
    gid = group_id(kind)
    if gid is not None:
        batch = specialize(lie_prior_batch, gid)

        def run(args, consts, with_jac):
            (x,), c = _prepared(name, kind, 1, args, consts)
            return batch(x, c, with_jac)

        def trusted(args, consts):
            return batch(args[0], consts, True)
        call = CompiledCall(__name__, "lie_prior_batch", prefix=f"{gid}, ", suffix=", True")
    elif _is_vector_kind(kind):
        def run(args, consts, with_jac):
            (x,), c = _prepared(name, kind, 1, args, consts)
            return vector_prior_batch(x, c, with_jac)

        def trusted(args, consts):
            return vector_prior_batch(args[0], consts, True)
        call = CompiledCall(__name__, "vector_prior_batch", suffix=", True")
    else:
        raise _unsupported("prior_kernel", kind)
    return FactorKernel(name, (kind,), kind.dim, kind.storage_dim,
                        residual=lambda args, consts: run(args, consts, False)[0],
                        linearize=lambda args, consts: run(args, consts, True),
                        source=_SOURCE, recipe=(prior_kernel, (kind,)),
                        trusted_linearize=trusted, compiled_call=call)
