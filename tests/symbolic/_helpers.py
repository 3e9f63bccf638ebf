"""Shared checks: evaluate symbolic expressions, central differences of batched kernels."""

from __future__ import annotations

import numpy as np

from fgopt.symbolic import python_function


def evaluator(symbols, exprs, output=None):
    """Numeric function of the symbols' values -> float array of ``exprs`` (via the printer).

    ``exprs``: a list of expressions, or a Program and the ``output`` name to return.
    """
    if output is not None:
        fn = python_function(list(symbols), exprs)
        return lambda *vals: np.array(fn(*[float(v) for v in vals])[output], dtype=float)
    fn = python_function(list(symbols), list(exprs))
    return lambda *vals: np.array(fn(*[float(v) for v in vals]), dtype=float)


def kernel_fd(kernel, args, consts, h=1e-6):
    """Central-difference Jacobian ``(r, D)`` of ``kernel.residual`` for one instance.

    ``args``: tuple of ``(1, s_i)`` storage arrays; perturbations use each kind's numeric
    (batched) retract, so this is the tangent-space Jacobian of the manifold's own retract.
    """
    cols = []
    for i, kind in enumerate(kernel.arg_kinds):
        for j in range(kind.dim):
            d = np.zeros((1, kind.dim))
            d[0, j] = h
            plus, minus = list(args), list(args)
            plus[i] = kind.retract(args[i], d)
            minus[i] = kind.retract(args[i], -d)
            rp = kernel.residual(tuple(plus), consts)[0]
            rm = kernel.residual(tuple(minus), consts)[0]
            cols.append((rp - rm) / (2 * h))
    return np.stack(cols, axis=1)


def assert_jacobian_matches_fd(kernel, args, consts, rtol=1e-6, h=1e-6):
    """``|J - J_fd|_max <= rtol * max(1, |J|_max)`` for one instance."""
    _, jac = kernel.linearize(args, consts)
    J = jac[0]
    Jfd = kernel_fd(kernel, args, consts, h)
    scale = max(1.0, float(np.abs(J).max()))
    err = float(np.abs(J - Jfd).max())
    assert err <= rtol * scale, f"{kernel.name}: |J - J_fd| = {err:.3e} (scale {scale:.3e})\nJ=\n{J}\nJfd=\n{Jfd}"
    return err / scale
