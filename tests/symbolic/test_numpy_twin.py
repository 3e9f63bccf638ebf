"""NumPy twins of generated kernels: the same program on whole columns gives the numba
kernel's residuals and Jacobians (every shipped built-in, a custom range-bearing factor, and
expressions with selects), and small batches run the twin without compiling numba."""

import numpy as np
import pytest

import fgopt
from fgopt.manifolds import SE2, SE3
from fgopt.symbolic import V2, Pose2, atan2
from fgopt.symbolic.printer import to_numpy_source
from fgopt.symbolic.runtime import NUMPY_MAX_BATCH


def _random_storage(kind, n, rng):
    if kind.name == "SE2":
        return np.stack([SE2.from_xytheta(*rng.normal(size=2), rng.uniform(-3, 3)).to_storage()
                         for _ in range(n)])
    if kind.name == "SE3":
        return np.stack([SE3.exp(rng.normal(size=6)).to_storage() for _ in range(n)])
    if kind.name == "SO2":
        t = rng.uniform(-3, 3, n)
        return np.stack([np.cos(t), np.sin(t)], axis=1)
    if kind.name == "SO3":
        q = rng.normal(size=(n, 4))
        return q / np.linalg.norm(q, axis=1, keepdims=True)
    return rng.normal(size=(n, kind.storage_dim))


@pytest.mark.parametrize("which", ["between_pose2", "prior_pose2", "between_pose3",
                                   "prior_pose3", "between_rot3", "bal_reprojection"])
def test_twin_equals_numba_kernel(which):
    """Residual and Jacobian of the twin equal the numba kernel's (random inputs, incl. small
    rotation angles) to rounding."""
    from fgopt.factors.library.shipped import builtin_kernels

    ftype, pattern = next((f, p) for f, p in builtin_kernels() if f.name == which)
    module = ftype.generated_module(pattern)
    kernel = ftype.kernel(pattern)
    rng = np.random.default_rng(3)
    n = 40
    args = [_random_storage(k, n, rng) for k in kernel.arg_kinds]
    if kernel.num_constants:
        consts = np.concatenate([_random_storage(k, n, rng) for k in kernel.arg_kinds[:1]],
                                axis=1)[:, :kernel.num_constants]
        if consts.shape[1] < kernel.num_constants:
            consts = rng.normal(size=(n, kernel.num_constants))
    else:
        consts = np.empty((n, 0))
    if args[0].shape == args[-1].shape:
        args[0][:5] = args[-1][:5]  # near-identity relative poses: the Taylor branches
    r_np, J_np = np.empty((n, kernel.residual_dim)), np.empty((n, kernel.residual_dim,
                                                               kernel.tangent_dim))
    with np.errstate(all="ignore"):
        module._linearize_numpy(*args, consts, r_np, J_np)
    r_nb, J_nb = np.empty_like(r_np), np.empty_like(J_np)
    module._linearize_kernel(*args, consts, r_nb, J_nb)
    ok = np.isfinite(r_nb).all(axis=1)
    assert ok.sum() > n // 2
    assert np.allclose(r_np[ok], r_nb[ok], rtol=1e-9, atol=1e-11)
    assert np.allclose(J_np[ok], J_nb[ok], rtol=1e-8, atol=1e-10)


def test_selects_and_min_max_print_as_ufuncs():
    """Heaviside, Min, Max and Abs print as elementwise NumPy (no Python ``if``/``min``); a
    function without a ufunc gives ``None`` (the module keeps only numba)."""
    import sympy as sp

    x, y = sp.symbols("x y")
    env = {"np": np, "EPSILON": 1e-12, "x": np.array([-1.0, 0.0, 2.0]),
           "y": np.array([0.5, 0.5, 0.5])}
    for expr, expected in [(sp.Heaviside(x), [0.0, 0.5, 1.0]), (sp.Min(x, y), [-1.0, 0.0, 0.5]),
                           (sp.Max(x, y), [0.5, 0.5, 2.0]), (sp.Abs(x) + sp.atan2(y, x),
                                                             np.abs([-1.0, 0, 2]) +
                                                             np.arctan2(0.5, [-1.0, 0, 2]))]:
        src = to_numpy_source(expr)
        assert src is not None and " if " not in src
        assert np.allclose(eval(src, env), expected)  # noqa: S307 - our own printed source
    assert to_numpy_source(sp.erf(x)) is None


def test_small_custom_factor_solves_without_compiling_its_kernel(tmp_path, monkeypatch):
    """A new range-bearing factor on a small problem runs its NumPy twin: its numba kernels are
    never built, and the solution equals the one through the numba kernel."""
    monkeypatch.setenv("FGOPT_CACHE_DIR", str(tmp_path))

    @fgopt.factor
    def rb_twin_check(pose: Pose2, landmark: V2, measured: V2) -> V2:
        d = pose.inverse() * landmark
        return V2(d.norm(), atan2(d[1], d[0])) - measured

    from fgopt import key

    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    graph.add(fgopt.PriorFactor(key("x", 0), SE2(), fgopt.noise.Isotropic.sigma(3, 0.01)))
    rng = np.random.default_rng(0)
    for j in range(6):
        lm = rng.normal(size=2) * 5
        graph.add(rb_twin_check(pose=key("x", 0), landmark=key("l", j),
                                measured=np.array([np.linalg.norm(lm), np.arctan2(lm[1], lm[0])])))
        initial.add(key("l", j), lm + rng.normal(size=2) * 0.3)
    initial.add(key("x", 0), SE2.from_xytheta(0.1, -0.1, 0.05))
    result = fgopt.optimize(graph, initial)
    module = rb_twin_check.generated_module(("pose", "landmark"))
    assert not module._linearize_kernel.compiled and not module._residual_kernel.compiled
    assert result.final_cost < 1e-12
    from fgopt.symbolic import runtime

    monkeypatch.setattr(runtime, "NUMPY_MAX_BATCH", 0)  # force the numba kernel
    again = fgopt.optimize(graph, initial, backend="numba")
    assert module._linearize_kernel.compiled
    for j in range(6):
        assert np.allclose(again.values.at(key("l", j)), result.values.at(key("l", j)),
                           atol=1e-9)
    assert NUMPY_MAX_BATCH >= 100
