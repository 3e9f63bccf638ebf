"""Generated kernel bodies written as LLVM IR (fgopt.symbolic._ir): the compiled kernel equals
the NumPy twin and the table's Python interpreter, on every operation the printer knows, at the
branch points of the selects, and on non-contiguous arrays."""

from __future__ import annotations

import numpy as np

import fgopt
from fgopt.symbolic import V2, V3, Abs, Max, Min, acos, atan2, exp, log, sign, sqrt, where
from fgopt.symbolic import sign_no_zero, tanh


@fgopt.factor
def ir_every_op(p: V3, q: V3, c: V2) -> V3:
    d = p - q
    return V3(atan2(d[1], d[0]) + Abs(d[2]) * c[0] + sign_no_zero(d[0]) * tanh(d[1]),
              where(Abs(d[0]) <= Abs(d[1]), d[0], Min(d[1], c[1])) + exp(0.1 * d[2])
              + log(1.0 + d.dot(d)),
              Max(d[0], d[2]) + sqrt(d.dot(d)) + sign(d[1]) + acos(Min(Max(d[0], -0.5), 0.5))
              + d[0] ** 3 / (1.0 + d[1] ** 2))


def _inputs(n: int, rng):
    p = rng.normal(size=(n, 3))
    q = rng.normal(size=(n, 3))
    q[:5] = p[:5]  # d = 0: sign, Heaviside and atan2 at their branch points
    q[5:10, 1] = p[5:10, 1] + (p[5:10, 0] - q[5:10, 0])  # |d0| == |d1|: where() at its edge
    return p, q, rng.normal(size=(n, 2)), np.empty((n, 0))  # every argument a variable


def test_compiled_body_equals_twin_and_interpreter():
    """Residual and Jacobian of the IR kernel equal the NumPy twin (same program, NumPy's
    operations: to 1e-13) and the interpreter of the same table (bit for bit, where finite)."""
    m = ir_every_op.generated_module()
    p, q, c, k0 = _inputs(64, np.random.default_rng(3))
    n, r, D = 64, m.META["residual_dim"], m.META["tangent_dim"]
    out = [(np.empty((n, r)), np.empty((n, r, D))) for _ in range(3)]
    m._linearize_kernel(p, q, c, k0, *out[0])
    with np.errstate(all="ignore"):
        m._linearize_numpy(p, q, c, k0, *out[1])
    for i in range(n):
        m._linearize_kernel_body(p, q, c, k0, *out[2], i)
    for k in range(2):
        np.testing.assert_allclose(out[0][k], out[1][k], rtol=1e-13, atol=1e-13)
        np.testing.assert_array_equal(out[0][k], out[2][k])


def test_compiled_body_on_strided_arrays():
    """The body indexes through strides: columns of a wider array (not C-contiguous) give the
    results of their contiguous copies."""
    m = ir_every_op.generated_module()
    p, q, c, k0 = _inputs(32, np.random.default_rng(4))
    wide = np.zeros((32, 9))
    wide[:, 0:3], wide[:, 3:6] = p, q
    r = m.META["residual_dim"]
    a, b = np.empty((32, r)), np.empty((32, r))
    m._residual_kernel(p, q, c, k0, a)
    m._residual_kernel(wide[:, 0:3], wide[:, 3:6], c, k0, b)
    np.testing.assert_array_equal(a, b)


def test_module_has_no_python_arithmetic_in_kernels():
    """The generated kernels are loops calling the body (numba types one call, not one per
    operation): the table carries the program."""
    src = ir_every_op.source
    kernel = src[src.index("def _linearize_kernel("):].split("\n\n")[0]
    assert "_linearize_kernel_body(" in kernel
    assert "=" not in kernel.split('"""')[-1].replace("==", "")
