"""Input helpers of :class:`~fgopt.filters.ekf.ManifoldEKF`: reading the user's functions,
and the error (class, message) of each status code of :mod:`fgopt.filters._ekf_kernels`."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from ..errors import (
    DimensionMismatchError,
    FgoptError,
    NonFiniteError,
    NotPositiveDefiniteError,
)
from . import _ekf_kernels as K


def step_error(code: int, idx: int, n: int, dt: float) -> tuple[type, str]:
    """Exception class and message of a kernel status ``code`` (``idx``: offending entry)."""
    cell = divmod(max(idx, 0), max(n, 1))
    msgs = {
        K.U_NONFINITE: (NonFiniteError, f"u[{idx}] is not finite"),
        K.DT_INVALID: (FgoptError, f"dt must be positive and finite, got {dt!r}"),
        K.Q_NONFINITE: (NonFiniteError, "Q is not finite"),
        K.Q_ASYMMETRIC: (NotPositiveDefiniteError, "Q is not symmetric"),
        K.Q_NOT_PSD: (NotPositiveDefiniteError, "Q is not positive semi-definite"),
        K.QS_NONFINITE: (NonFiniteError, "Q_state is not finite"),
        K.QS_ASYMMETRIC: (NotPositiveDefiniteError, "Q_state is not symmetric"),
        K.QS_NOT_PSD: (NotPositiveDefiniteError, "Q_state is not positive semi-definite"),
        K.PROCESS_NONFINITE: (NonFiniteError, (f"the process function returned a non-finite "
                                              f"state (storage entry {idx})")),
        K.JACOBIAN_NONFINITE: (NonFiniteError, "a generated Jacobian is not finite"),
        K.COVARIANCE_NONFINITE: (NonFiniteError, (f"the covariance would become non-finite "
                                                 f"(entry {cell})")),
        K.R_NONFINITE: (NonFiniteError, "R is not finite"),
        K.R_ASYMMETRIC: (NotPositiveDefiniteError, "R is not symmetric"),
        K.R_NOT_PD: (NotPositiveDefiniteError, "R is not positive definite"),
        K.INNOVATION_NONFINITE: (NonFiniteError, f"the innovation is not finite (entry {idx})"),
        K.S_NOT_PD: (NotPositiveDefiniteError, ("the innovation covariance H P H^T + R is not "
                                               "positive definite")),
        K.RETRACT_NONFINITE: (NonFiniteError, "the corrected state is not finite"),
        K.Z_NONFINITE: (NonFiniteError, f"z[{idx}] is not finite"),
    }
    return msgs.get(code, (FgoptError, f"failed (code {code})"))


def signature(fn: Callable, what: str, scope: dict | None = None) -> list:
    """``[(name, symbolic type)]`` of a function's annotated parameters."""
    from ..symbolic.generated import parameters

    if not callable(fn):
        raise FgoptError(f"ManifoldEKF: the {what} function is not callable: {fn!r}")
    return list(parameters(fn, getattr(fn, "__name__", what), scope))


def return_type(fn: Callable, scope: dict | None = None) -> type | None:
    from ..symbolic.generated import type_hints
    from ..symbolic.ops import normalize_type

    try:
        rt = type_hints(fn, scope).get("return")
        return None if rt is None else normalize_type(rt)
    except Exception:  # noqa: BLE001 - unresolvable or unsupported: derive it instead
        return None


def named(measurements: Any) -> dict:
    if measurements is None:
        return {}
    if isinstance(measurements, Mapping):
        return dict(measurements)
    if callable(measurements):
        measurements = [measurements]
    out = {}
    for fn in measurements:
        name = getattr(fn, "__name__", None)
        if name is None or not name.isidentifier() or name in out:
            raise FgoptError("ManifoldEKF: measurement functions given as a sequence need "
                             "distinct names (or pass a dict name -> function)")
        out[name] = fn
    return out


def fresh_names(wanted: list, taken: set) -> list:
    out = []
    for w in wanted:
        name = w
        while name in taken:
            name += "_"
        taken.add(name)
        out.append(name)
    return out


def default_state(process: Callable, params: list, dt: str, name: str,
                  scope: dict | None = None) -> tuple:
    """The first k arguments, k = number of returned values (from the return annotation,
    else from a value-only generated module, which needs no SymPy on a cache hit)."""
    import typing

    from ..symbolic.generated import GeneratedFunction, type_hints

    try:
        rt = type_hints(process, scope).get("return")
    except Exception:  # noqa: BLE001 - unresolvable: count the outputs instead
        rt = None
    if rt is not None and typing.get_origin(rt) is tuple:
        k = len([a for a in typing.get_args(rt) if a is not Ellipsis])
    elif rt is not None:
        k = 1
    else:
        k = len(GeneratedFunction(process, which=(), name=f"{name}_outputs", method="retraction",
                                  engine="auto", cache=True, scope=scope).outputs)
    cand = tuple(n for n, _ in params if n != dt)[:k]
    if len(cand) < k:
        raise FgoptError(f"ManifoldEKF {name}: the process returns {k} values but has "
                         f"only {len(cand)} arguments besides '{dt}'")
    return cand


def as_vector(v: Any, n: int, what: str, layout: str) -> np.ndarray:
    """``v`` as ``n`` floats, or a DimensionMismatchError naming ``what`` and its layout."""
    try:
        arr = np.asarray(v, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise DimensionMismatchError(f"{what} must be {n} numbers, got {v!r}") from None
    if arr.shape[0] != n:
        raise DimensionMismatchError(f"{what} needs {n} numbers ({layout}), got {arr.shape[0]}")
    return arr


def as_matrix(A: Any, shape: tuple, what: str) -> np.ndarray:
    """``A`` (or the diagonal of variances it lists) as a C-contiguous ``shape`` array."""
    try:
        arr = np.array(A, dtype=np.float64)
    except (TypeError, ValueError):
        raise DimensionMismatchError(f"{what} must be a {shape[0]}x{shape[1]} matrix, got "
                                     f"{A!r}") from None
    if arr.ndim == 1 and arr.shape[0] == shape[0]:
        arr = np.diag(arr)
    if arr.shape != shape:
        raise DimensionMismatchError(f"{what} must be {shape[0]}x{shape[1]}, got shape "
                                     f"{arr.shape}")
    return np.ascontiguousarray(arr)
