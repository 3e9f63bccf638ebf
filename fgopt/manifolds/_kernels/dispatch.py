"""Dispatch over a group id (``lie_compose(gid, ...)``...) and the batched loops over (n, storage) arrays, with the per-group ``BatchKind`` entries.

The dispatchers and loops are inlined (numba IR) into entries with a constant id
(:func:`fgopt._jit.specialize`): numba prunes the other groups' branches before typing them,
so a problem compiles its own groups' code only (Sim(3)'s alone took ~2.5 s).

Part of :mod:`fgopt.manifolds._kernels` (conventions in its docstring).
"""

from __future__ import annotations

import sys

import numpy as np
from ..._jit import njit, numpy_only, specialize

from ._common import (
    GROUP_NAMES, MAX_STORAGE_DIM, SE2_ID, SE3_ID, SO2_ID, SO3_ID, storage_dim, tangent_dim,
)
from .vectorized import RETRACT_NUMPY
from .so2 import so2_ad, so2_compose, so2_exp, so2_eye, so2_inverse, so2_log
from .se2 import se2_ad, se2_adjoint, se2_compose, se2_exp, se2_inverse, se2_jr, se2_jrinv, se2_log
from .so3 import so3_ad, so3_adjoint, so3_compose, so3_exp, so3_inverse, so3_jr, so3_jrinv, so3_log
from .se3 import se3_ad, se3_adjoint, se3_compose, se3_exp, se3_inverse, se3_jr, se3_jrinv, se3_log
from .sim3 import (
    sim3_ad, sim3_adjoint, sim3_compose, sim3_exp, sim3_inverse, sim3_jr, sim3_jrinv,
    sim3_log,
)


@njit(cache=True, inline="always")
def lie_compose(gid, a, b, out):
    """out = a * b for group ``gid`` (out must not alias a or b)."""
    if gid == SO2_ID:
        so2_compose(a, b, out)
    elif gid == SE2_ID:
        se2_compose(a, b, out)
    elif gid == SO3_ID:
        so3_compose(a, b, out)
    elif gid == SE3_ID:
        se3_compose(a, b, out)
    else:
        sim3_compose(a, b, out)


@njit(cache=True, inline="always")
def lie_inverse(gid, a, out):
    if gid == SO2_ID:
        so2_inverse(a, out)
    elif gid == SE2_ID:
        se2_inverse(a, out)
    elif gid == SO3_ID:
        so3_inverse(a, out)
    elif gid == SE3_ID:
        se3_inverse(a, out)
    else:
        sim3_inverse(a, out)


@njit(cache=True, inline="always")
def lie_exp(gid, v, out):
    if gid == SO2_ID:
        so2_exp(v, out)
    elif gid == SE2_ID:
        se2_exp(v, out)
    elif gid == SO3_ID:
        so3_exp(v, out)
    elif gid == SE3_ID:
        se3_exp(v, out)
    else:
        sim3_exp(v, out)


@njit(cache=True, inline="always")
def lie_log(gid, a, out):
    if gid == SO2_ID:
        so2_log(a, out)
    elif gid == SE2_ID:
        se2_log(a, out)
    elif gid == SO3_ID:
        so3_log(a, out)
    elif gid == SE3_ID:
        se3_log(a, out)
    else:
        sim3_log(a, out)


@njit(cache=True, inline="always")
def lie_adjoint(gid, a, out):
    if gid == SO2_ID:
        so2_eye(a, out)
    elif gid == SE2_ID:
        se2_adjoint(a, out)
    elif gid == SO3_ID:
        so3_adjoint(a, out)
    elif gid == SE3_ID:
        se3_adjoint(a, out)
    else:
        sim3_adjoint(a, out)


@njit(cache=True, inline="always")
def lie_ad(gid, v, out):
    if gid == SO2_ID:
        so2_ad(v, out)
    elif gid == SE2_ID:
        se2_ad(v, out)
    elif gid == SO3_ID:
        so3_ad(v, out)
    elif gid == SE3_ID:
        se3_ad(v, out)
    else:
        sim3_ad(v, out)


@njit(cache=True, inline="always")
def lie_jr(gid, v, out):
    if gid == SO2_ID:
        so2_eye(v, out)
    elif gid == SE2_ID:
        se2_jr(v, out)
    elif gid == SO3_ID:
        so3_jr(v, out)
    elif gid == SE3_ID:
        se3_jr(v, out)
    else:
        sim3_jr(v, out)


@njit(cache=True, inline="always")
def lie_jrinv(gid, v, out):
    if gid == SO2_ID:
        so2_eye(v, out)
    elif gid == SE2_ID:
        se2_jrinv(v, out)
    elif gid == SO3_ID:
        so3_jrinv(v, out)
    elif gid == SE3_ID:
        se3_jrinv(v, out)
    else:
        sim3_jrinv(v, out)


# (reference counting explicit: numba compiles a callee without its own _nrt with its caller's,
# and the small drivers' retract counts none while Sim(3)'s exp allocates)
@njit(cache=True, _nrt=True)
def lie_retract(gid, x, delta, out, tmp):
    """out = x * Exp(delta); ``tmp`` is scratch of length >= storage dim."""
    lie_exp(gid, delta, tmp)
    lie_compose(gid, x, tmp, out)


@njit(cache=True, inline="always")
def lie_local(gid, a, b, out, tmp1, tmp2):
    """out = Log(a^-1 * b); ``tmp1``, ``tmp2`` are scratch of length >= storage dim."""
    lie_inverse(gid, a, tmp1)
    lie_compose(gid, tmp1, b, tmp2)
    lie_log(gid, tmp2, out)


# The common groups' exp / compose inlined into batch_retract's loop (numba IR inlining): the
# per-row calls through lie_retract's group switch, with an array view per argument, measured
# 3x (SE(2)) / 2.3x (SE(3)) slower on 808 rows (a pose graph's retract: 77 -> 26 us). The
# per-group entries prune the switch; the small drivers' retract switches per row.
def _inlined(kernel):
    return njit(inline="always")(kernel.py_func)


_se2_exp, _se2_compose = _inlined(se2_exp), _inlined(se2_compose)
_se3_exp, _se3_compose = _inlined(se3_exp), _inlined(se3_compose)
_so3_exp, _so3_compose = _inlined(so3_exp), _inlined(so3_compose)
_so2_exp, _so2_compose = _inlined(so2_exp), _inlined(so2_compose)


@njit(cache=True, inline="always")
def retract_row(gid, x, delta, out, tmp):
    """``out = x * Exp(delta)``: :func:`lie_retract` with the common groups inlined."""
    if gid == SE3_ID:
        _se3_exp(delta, tmp)
        _se3_compose(x, tmp, out)
    elif gid == SE2_ID:
        _se2_exp(delta, tmp)
        _se2_compose(x, tmp, out)
    elif gid == SO3_ID:
        _so3_exp(delta, tmp)
        _so3_compose(x, tmp, out)
    elif gid == SO2_ID:
        _so2_exp(delta, tmp)
        _so2_compose(x, tmp, out)
    else:
        lie_retract(gid, x, delta, out, tmp)


@njit(cache=True, inline="always")
def batch_retract(gid, x, delta):
    """(n, s), (n, d) -> (n, s): row-wise x * Exp(delta)."""
    out = np.empty((x.shape[0], storage_dim(gid)))
    tmp = np.empty(MAX_STORAGE_DIM)
    for i in range(x.shape[0]):
        retract_row(gid, x[i], delta[i], out[i], tmp)
    return out


@njit(cache=True, inline="always")
def batch_retract_rows(gid, x, delta, rows, out):
    """``out[v] = x[v] * Exp(delta[v])`` for each ``v`` of ``rows``, in place (``out`` may be
    ``x``; ``delta`` may have more columns than the tangent dim): the incremental smoother's
    gather, retract and scatter of a few rows in one call, where each NumPy step cost more
    than the retraction."""
    tmp = np.empty(MAX_STORAGE_DIM)
    row = np.empty(storage_dim(gid))
    for v in rows:
        row[:] = x[v]
        retract_row(gid, row, delta[v], out[v], tmp)


@njit(cache=True, inline="always")
def batch_local(gid, a, b):
    """(n, s), (n, s) -> (n, d): row-wise Log(a^-1 * b)."""
    out = np.empty((a.shape[0], tangent_dim(gid)))
    tmp1 = np.empty(MAX_STORAGE_DIM)
    tmp2 = np.empty(MAX_STORAGE_DIM)
    for i in range(a.shape[0]):
        lie_local(gid, a[i], b[i], out[i], tmp1, tmp2)
    return out


#: Batches of at most this many rows run the loops as plain Python while numba is not in use in
#: the process (a small problem's retract then needs no numba import or cache load).
PYTHON_MAX_ROWS = 64


def _entry(loop, gid: int, name: str, vectorized=None):
    compiled = specialize(loop, gid)  # compiles group gid's code only

    def run(a, b):
        a = np.ascontiguousarray(a, dtype=np.float64)
        b = np.ascontiguousarray(b, dtype=np.float64)
        if vectorized is not None and (numpy_only() or "numba" not in sys.modules):
            return vectorized(a, b)  # NumPy backend, or numba not in use: no numba import
        if a.shape[0] <= PYTHON_MAX_ROWS and "numba" not in sys.modules:
            return loop.python(gid, a, b)
        return compiled(a, b)

    #: True when the NumPy backend can run this without numba (``Problem(backend=)``)
    run.numpy = vectorized is not None
    #: The compiled loop alone, for callers that already hold C-contiguous float64 rows and use
    #: numba anyway (the incremental smoother: ~3 us less per call than ``run``'s checks)
    run.compiled = compiled
    run.__name__ = run.__qualname__ = name
    run.__doc__ = f"Batched {name.split('_')[1]} of {GROUP_NAMES[gid]} over (n, storage) rows."
    return run


RETRACT_BATCH = tuple(_entry(batch_retract, g, f"{GROUP_NAMES[g].lower()}_retract_batch",
                             RETRACT_NUMPY[g]) for g in range(5))
for _g, _run in enumerate(RETRACT_BATCH):
    _run.gid = _g  # (for retract_rows)


def retract_rows(gid: int):
    """``batch_retract_rows`` of group ``gid``, compiled for it alone:
    ``retract_rows(gid)(x, delta, rows, out)`` (C-contiguous float64 arrays, int64 rows; no
    checks)."""
    return specialize(batch_retract_rows, gid)


LOCAL_BATCH = tuple(_entry(batch_local, g, f"{GROUP_NAMES[g].lower()}_local_batch")
                    for g in range(5))


so2_retract_batch, se2_retract_batch, so3_retract_batch, se3_retract_batch, \
    sim3_retract_batch = RETRACT_BATCH


so2_local_batch, se2_local_batch, so3_local_batch, se3_local_batch, sim3_local_batch = LOCAL_BATCH
