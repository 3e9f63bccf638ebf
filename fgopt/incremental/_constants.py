"""Constant keys of the incremental smoother: factors over them become factors over the other
keys, with the constant values among their constants.

A key held constant never enters the Bayes tree (no tangent, no column, no clique): each factor
touching it is rewritten as a factor of its remaining keys whose kernel
(:func:`with_constant_arguments`) runs the original kernel with the constant's storage put back
in place and drops that argument's Jacobian columns. The value is read from the smoother's
table of constants, so it stays bit for bit what the caller gave.
"""

from __future__ import annotations

import numpy as np

from ..errors import FgoptError, ManifoldError
from ..factors.base import Factor, KernelFactor
from ..factors.kernel import FactorKernel
from ..key import key_str
from ..manifolds.base import ops_for

#: (id(kernel), mask) -> (kernel, wrapped kernel): one wrapped kernel per kernel and set of
#: constant arguments, so the rewritten factors share batches
_WRAPPED: dict = {}


def with_constant_arguments(kernel: FactorKernel, mask: tuple) -> FactorKernel:
    """``kernel`` with the arguments where ``mask`` is True taken from the constants: its
    constants are ``kernel``'s, then those arguments' storages in order; residuals are
    ``kernel``'s, Jacobians its columns of the other arguments."""
    hit = _WRAPPED.get((id(kernel), mask))
    if hit is not None:
        return hit[1]
    kinds, nc = kernel.arg_kinds, kernel.num_constants
    starts = np.cumsum([0] + [k.dim for k in kinds])
    cols = np.concatenate([np.arange(starts[j], starts[j + 1]) for j, c in enumerate(mask)
                           if not c])
    spans, at = [], nc
    for j, c in enumerate(mask):
        spans.append((at, at + kinds[j].storage_dim) if c else None)
        at += kinds[j].storage_dim if c else 0

    def full(args: tuple, consts: np.ndarray) -> tuple[tuple, np.ndarray]:
        it = iter(args)
        return (tuple(next(it) if s is None else np.ascontiguousarray(consts[:, s[0]:s[1]])
                      for s in spans), np.ascontiguousarray(consts[:, :nc]))

    def residual(args: tuple, consts: np.ndarray) -> np.ndarray:
        return kernel.residual(*full(args, consts))

    def linearize(args: tuple, consts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        res, jac = kernel.linearize(*full(args, consts))
        return res, np.ascontiguousarray(jac[:, :, cols])

    which = ", ".join(str(j) for j, c in enumerate(mask) if c)
    wrapped = FactorKernel(name=f"{kernel.name} (argument {which} constant)",
                           arg_kinds=tuple(k for k, c in zip(kinds, mask) if not c),
                           residual_dim=kernel.residual_dim, num_constants=at,
                           residual=residual, linearize=linearize, source=kernel.source,
                           nonfinite_hint=kernel.nonfinite_hint, numpy_twin=kernel.numpy_twin)
    _WRAPPED[(id(kernel), mask)] = (kernel, wrapped)
    return wrapped


def substitute(f: Factor, constants: dict) -> Factor:
    """``f`` with the keys in ``constants`` (key -> value) replaced by their values (``f``
    itself when it uses none)."""
    mask = tuple(k in constants for k in f.keys)
    if not any(mask):
        return f
    if f.kernel is None:
        raise FgoptError(f"update: {f.describe()} uses the constant key "
                         f"{key_str(f.keys[mask.index(True)])}; only kernel factors (built-in "
                         "ones, @fgopt.factor) take constant keys in the smoother")
    if all(mask):
        raise FgoptError(f"update: every key of {f.describe()} is constant, so it cannot change "
                         "the estimate: leave it out")
    storages = [f.constants]
    for k, kind, c in zip(f.keys, f.kernel.arg_kinds, mask):
        if c:
            x = constants[k]
            if ops_for(x).batch_kind(x) is not kind:
                raise ManifoldError(f"update: {f.describe()} expects {kind.name} for "
                                    f"{key_str(k)}, but its constant value is a "
                                    f"{type(x).__name__}")
            storages.append(np.asarray(kind.to_storage(x), dtype=float).reshape(-1))
    return KernelFactor(with_constant_arguments(f.kernel, mask),
                        [k for k, c in zip(f.keys, mask) if not c], np.concatenate(storages),
                        f.loss)
