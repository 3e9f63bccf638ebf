"""Input helpers of :class:`~fgopt.filters.ekf.ManifoldEKF`: reading the user's functions,
and the error (class, message) of each status code of :mod:`fgopt.filters._ekf_kernels`."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from ..errors import FgoptError, NonFiniteError, NotPositiveDefiniteError
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


def signature(fn: Callable, what: str) -> list:
    """``[(name, symbolic type)]`` of a function's annotated parameters."""
    from ..symbolic.generate import parameters

    if not callable(fn):
        raise FgoptError(f"ManifoldEKF: the {what} function is not callable: {fn!r}")
    return list(parameters(fn, getattr(fn, "__name__", what), None))


def return_type(fn: Callable) -> type | None:
    from ..symbolic.generate import type_hints
    from ..symbolic.ops import normalize_type

    try:
        rt = type_hints(fn, None).get("return")
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
