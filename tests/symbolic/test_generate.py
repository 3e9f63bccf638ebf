"""fgopt.symbolic.generate: generated functions and their tangent-space Jacobians.

Every Jacobian is checked against central differences taken through the numeric retraction of
each argument (``x * Exp(d)`` with fgopt.manifolds' groups) and the local coordinates of each
output (``Log(y^-1 y')``), at generic points and at rotations near 0 and near pi.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numba
import numpy as np
import pytest

import fgopt
from fgopt.manifolds import SE2, SE3, SO3
from fgopt.symbolic import (
    M33,
    V2,
    V3,
    Matrix,
    Pose2,
    Pose3,
    Rot3,
    Scalar,
    cache,
    generate,
)

RNG = np.random.default_rng(7)


# ---------------------------------------------------------------------- functions under test
def rot_step(R: Rot3, w: V3, dt: Scalar) -> Rot3:
    return R * Rot3.exp(w * dt)


def strapdown(R: Rot3, p: V3, v: V3, gyro: V3, accel: V3, dt: Scalar):
    a = R * accel + V3(0, 0, -9.81)
    return R * Rot3.exp(gyro * dt), p + v * dt + a * (dt * dt / 2), v + a * dt, a.norm()


def relative(a: Pose3, b: Pose3) -> Pose3:
    return a.inverse() * b


def to_body(a: Pose3, p: V3) -> V3:
    return a.inverse() * p


def planar(a: Pose2, b: Pose2, scale: Scalar):
    return a.between(b), (a * V2(scale, 0.0))


def rotation_matrix(R: Rot3) -> M33:
    return R.matrix()


def log_of_product(a: Rot3, b: Rot3) -> V3:
    return (a * b).log()


# ---------------------------------------------------------------------- numeric helpers
def _retract(tp, x, d):
    if hasattr(x, "retract"):  # groups and declared manifolds (numeric values)
        return x.retract(d)
    if tp is Scalar:
        return x + d[0]
    return np.asarray(x, dtype=float) + d.reshape(np.shape(x))


def _local(y, y2):
    if hasattr(y, "local"):
        return y.local(y2)
    return np.atleast_1d(np.asarray(y2, dtype=float) - np.asarray(y, dtype=float)).reshape(-1)


def central_differences(gf, args, h=1e-6):
    """The stacked Jacobian by central differences through retract / local."""
    types = dict(gf.params)
    names = [n for n, _ in gf.params]
    y0 = gf.value(*args)
    outs0 = y0 if gf.tuple_output else (y0,)
    cols = []
    for name in gf.which:
        i, tp = names.index(name), types[name]
        for j in range(tp.dim()):
            e = np.zeros(tp.dim())
            e[j] = h
            plus, minus = list(args), list(args)
            plus[i] = _retract(tp, args[i], e)
            minus[i] = _retract(tp, args[i], -e)
            yp, ym = gf.value(*plus), gf.value(*minus)
            yp, ym = (yp, ym) if gf.tuple_output else ((yp,), (ym,))
            cols.append(np.concatenate([(_local(o, a) - _local(o, b)) / (2 * h)
                                        for o, a, b in zip(outs0, yp, ym)]))
    return np.stack(cols, axis=1)


def assert_matches_fd(gf, args, rtol=1e-6):
    _, J = gf(*args)
    Jfd = central_differences(gf, args)
    assert J.shape == Jfd.shape == gf.jacobian_shape
    scale = max(1.0, float(np.abs(J).max()))
    err = float(np.abs(J - Jfd).max())
    assert err <= rtol * scale, f"{gf.name}: |J - J_fd| = {err:.3e}\nJ=\n{J}\nJfd=\n{Jfd}"


def near_pi_rotation(rng, eps=1e-5):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return SO3.from_rotvec(axis * (np.pi - eps))


ROTATIONS = {
    "random": lambda rng: SO3.random(rng),
    "near_identity": lambda rng: SO3.from_rotvec(1e-9 * rng.normal(size=3)),
    "identity": lambda rng: SO3(),
    "near_pi": near_pi_rotation,
}


@pytest.fixture(scope="module")
def rot_step_fn():
    return generate(rot_step, which=["R", "w"])


# ---------------------------------------------------------------------- Jacobians vs FD
@pytest.mark.parametrize("where", list(ROTATIONS))
@pytest.mark.parametrize("rate", ["generic", "zero", "near_pi_step"])
def test_rotation_step_jacobians_match_fd(rot_step_fn, where, rate):
    """R Exp(w dt): both Jacobian blocks equal central differences through SO(3)'s retraction,
    for R random / at and near the identity / near pi, and w dt generic, 0, or a step near pi."""
    rng = np.random.default_rng(1)
    R = ROTATIONS[where](rng)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    w = {"generic": np.array([0.4, -0.2, 0.7]), "zero": np.zeros(3),
         "near_pi_step": axis * (np.pi - 1e-4) / 0.5}[rate]
    assert_matches_fd(rot_step_fn, [R, w, 0.5])


def test_rotation_step_has_the_textbook_jacobians(rot_step_fn):
    """d(R Exp(w dt))/dR = Exp(w dt)^T and d/dw = J_r(w dt) dt (right Jacobian of SO(3))."""
    R, w, dt = SO3.random(RNG), np.array([0.3, -0.8, 0.5]), 0.7
    R1, J = rot_step_fn(R, w, dt)
    phi = w * dt
    th = np.linalg.norm(phi)
    K = np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]])
    Jr = np.eye(3) - (1 - np.cos(th)) / th**2 * K + (th - np.sin(th)) / th**3 * K @ K
    assert np.allclose(J[:, :3], SO3.exp(phi).matrix().T, atol=1e-12)
    assert np.allclose(J[:, 3:], Jr * dt, atol=1e-12)
    assert R1.equals(R * SO3.exp(phi), 1e-12)


@pytest.mark.parametrize("where", ["random", "near_identity", "near_pi"])
def test_multiple_mixed_outputs_match_fd(where):
    """A strapdown step returning (Rot3, V3, V3, Scalar): stacked rows in each output's tangent
    space, columns for five arguments, equal to central differences."""
    gf = generate(strapdown, which=["R", "p", "v", "gyro", "accel"])
    assert gf.tuple_output and gf.jacobian_shape == (10, 15)
    assert [o.type.__name__ for o in gf.outputs] == ["Rot3", "V3", "V3", "Scalar"]
    rng = np.random.default_rng(3)
    args = [ROTATIONS[where](rng), rng.normal(size=3), rng.normal(size=3) * 5,
            rng.normal(size=3) * 0.3, rng.normal(size=3) + [0, 0, 9.8], 0.05]
    assert_matches_fd(gf, args)
    (R1, p1, _v1, anorm), J = gf(*args)
    assert isinstance(R1, SO3) and p1.shape == (3,) and isinstance(anorm, float)
    assert J[gf.rows[1], gf.cols["v"]] == pytest.approx(np.eye(3) * 0.05)


@pytest.mark.parametrize("where", ["random", "near_identity", "near_pi"])
def test_pose3_outputs_match_fd(where):
    """Pose3 output (a^-1 b) and a V3 output (a^-1 p) with Pose3 arguments whose rotation is
    generic, near the identity or near pi."""
    rng = np.random.default_rng(5)
    a = SE3(ROTATIONS[where](rng), rng.normal(size=3))
    b = SE3.random(rng)
    assert_matches_fd(generate(relative), [a, b])
    assert_matches_fd(generate(to_body), [a, rng.normal(size=3)])


def test_planar_tuple_and_scalar_argument_match_fd():
    """Pose2 between and a V2 output, differentiated also by a Scalar argument."""
    gf = generate(planar, which=["scale", "a", "b"])
    assert gf.jacobian_shape == (5, 7) and gf.cols["scale"] == slice(0, 1)
    assert_matches_fd(gf, [SE2.from_xytheta(1.0, -2.0, 0.4), SE2.from_xytheta(0.5, 0.3, -2.9),
                           1.7])


def test_matrix_output_rows_are_row_major_entries():
    """An M33 output has 9 Jacobian rows (its entries, row-major), equal to FD."""
    gf = generate(rotation_matrix)
    assert gf.jacobian_shape == (9, 3)
    R = SO3.random(RNG)
    M, _J = gf(R)
    assert np.allclose(M, R.matrix(), atol=1e-12)
    assert_matches_fd(gf, [R])


@pytest.mark.parametrize("where", ["random", "near_pi"])
def test_log_output_matches_fd(where):
    """A vector output built with Log (epsilon-safe) near pi and generically."""
    rng = np.random.default_rng(11)
    a = ROTATIONS[where](rng)
    b = SO3.from_rotvec(1e-3 * rng.normal(size=3))
    assert_matches_fd(generate(log_of_product), [a, b], rtol=1e-5)


@pytest.mark.parametrize("where", ["random", "near_pi"])
def test_declared_manifold_arguments_and_outputs_match_fd(where):
    """A manifold declared with @fgopt.manifold (SE_2(3)) as argument and output: rows in its
    own tangent space (its declared local), columns through its declared retract, equal to FD;
    the output comes back as the declaration's numeric value type."""
    from fgopt.symbolic import SE23, V9

    def extended_step(X: SE23, xi: V9, p: V3):
        return X.retract(xi), X.rotation() * (p - X.position())

    gf = generate(extended_step)
    assert gf.jacobian_shape == (12, 21) and gf.outputs[0].type is SE23
    rng = np.random.default_rng(13)
    xi = rng.normal(size=9)
    if where == "near_pi":
        axis = rng.normal(size=3)
        xi[:3] = axis / np.linalg.norm(axis) * (np.pi - 1e-5)
    X = SE23.Value.identity().retract(xi)
    args = [X, rng.normal(size=9) * 0.3, rng.normal(size=3)]
    assert_matches_fd(gf, args, rtol=2e-6)
    (X1, _), _ = gf(*args)
    assert isinstance(X1, SE23.Value) and X1.equals(X.retract(args[1]), 1e-12)


# ---------------------------------------------------------------------- API behaviour
def test_which_orders_the_column_blocks(rot_step_fn):
    """which=["w", "R"] gives the same blocks as ["R", "w"], swapped; dt alone is one column."""
    R, w = SO3.random(RNG), RNG.normal(size=3)
    _, J = rot_step_fn(R, w, 0.2)
    _, Jswap = generate(rot_step, which=["w", "R"])(R, w, 0.2)
    # the same derivatives; CSE may order the arithmetic differently (rounding only)
    assert np.allclose(Jswap[:, :3], J[:, 3:], rtol=0, atol=1e-14)
    assert np.allclose(Jswap[:, 3:], J[:, :3], rtol=0, atol=1e-14)
    gdt = generate(rot_step, which="dt")
    assert gdt.jacobian_shape == (3, 1)
    assert_matches_fd(gdt, [R, w, 0.2])


def test_no_which_gives_values_only(rot_step_fn):
    """which=() generates no Jacobian: the call returns the value, equal to the full call's."""
    g = generate(rot_step, which=())
    R, w = SO3.random(RNG), RNG.normal(size=3)
    assert g(R, w, 0.1).equals(rot_step_fn(R, w, 0.1)[0], 1e-14)
    assert g.ops["jacobian"] == 0 and "no jacobian" in repr(g)


def test_keyword_arguments_and_storage_vectors(rot_step_fn):
    """Arguments by keyword; a group argument may be given as its storage vector."""
    R, w = SO3.random(RNG), RNG.normal(size=3)
    a = rot_step_fn(R, w, 0.1)
    b = rot_step_fn(dt=0.1, w=w, R=R.to_storage())
    assert a[0].equals(b[0], 1e-15) and np.array_equal(a[1], b[1])


def test_batch_equals_single_calls(rot_step_fn):
    """batch(): (n, storage) arrays and a broadcast scalar give the single calls' results."""
    n = 6
    Rs = [SO3.random(RNG) for _ in range(n)]
    ws = RNG.normal(size=(n, 3))
    out, jac = rot_step_fn.batch(np.stack([r.to_storage() for r in Rs]), ws, 0.3)
    assert out.shape == (n, 4) and jac.shape == (n, 3, 6)
    for k in range(n):
        R1, J = rot_step_fn(Rs[k], ws[k], 0.3)
        assert np.allclose(out[k], R1.to_storage()) or np.allclose(out[k], -R1.to_storage())
        assert np.allclose(jac[k], J, atol=1e-14)
    outs, _ = generate(strapdown).batch(Rs, np.zeros((n, 3)), ws, ws, ws, np.full(n, 0.1))
    assert len(outs) == 4 and outs[3].shape == (n, 1)


def test_flat_is_callable_from_numba(rot_step_fn):
    """f.flat is an njit function other numba code can call (here in a loop of 100 steps)."""
    flat = rot_step_fn.flat

    @numba.njit
    def integrate(q, w, dt, steps):
        inp, out, jac = np.empty(8), np.empty(4), np.empty((3, 6))
        inp[:4] = q
        inp[4:7] = w
        inp[7] = dt
        for _ in range(steps):
            flat(inp, out, jac)
            inp[:4] = out
        return inp[:4].copy()

    w = np.array([0.1, 0.2, -0.3])
    q = integrate(np.array([0.0, 0.0, 0.0, 1.0]), w, 0.01, 100)
    assert SO3(q).equals(SO3.exp(w), 1e-12)


def test_second_generate_loads_the_cached_module():
    """Generating the same function again derives nothing (the module comes from the cache)."""
    generate(to_body)
    derived = cache.STATS["derived"]
    g = generate(to_body)
    assert cache.STATS["derived"] == derived
    assert Path(g.module.__file__).parent == cache.cache_dir()
    assert "Do NOT modify by hand" in g.source and "def flat(" in g.source


def test_repr_names_signature_and_jacobian(rot_step_fn):
    """The repr shows the signature, outputs, which and the Jacobian shape."""
    r = repr(rot_step_fn)
    assert "rot_step(R: Rot3, w: V3, dt: Scalar) -> Rot3" in r and "d/d(R, w) 3x6" in r


# ---------------------------------------------------------------------- bad input
def test_bad_arguments_raise_fgopt_errors_naming_the_argument(rot_step_fn):
    """Wrong sizes, non-finite values, wrong group types and missing / unknown arguments."""
    R = SO3()
    with pytest.raises(fgopt.FgoptError, match="'w'.*3 numbers"):
        rot_step_fn(R, np.zeros(4), 0.1)
    with pytest.raises(fgopt.FgoptError, match="'dt' is not finite"):
        rot_step_fn(R, np.zeros(3), np.nan)
    with pytest.raises(fgopt.FgoptError, match="'R' is a Rot3; got a SE3"):
        rot_step_fn(SE3(), np.zeros(3), 0.1)
    with pytest.raises(fgopt.FgoptError, match="missing argument"):
        rot_step_fn(R, np.zeros(3))
    with pytest.raises(fgopt.FgoptError, match="unknown argument 'x'"):
        rot_step_fn(R, np.zeros(3), 0.1, x=1.0)
    with pytest.raises(fgopt.FgoptError, match="'w' has 2 rows"):
        rot_step_fn.batch(np.tile(R.to_storage(), (3, 1)), np.zeros((2, 3)), 0.1)


def test_bad_functions_raise_fgopt_errors():
    """Missing annotations, unknown which names, symbolic branches, wrong return annotation."""
    def unannotated(x: V3, y):
        return x

    def branching(x: Scalar) -> Scalar:
        return x if x > 0 else -x

    def wrong_return(x: V3) -> Rot3:
        return x

    with pytest.raises(fgopt.FgoptError, match="'y' needs a type annotation"):
        generate(unannotated)
    with pytest.raises(fgopt.FgoptError, match="unknown argument"):
        generate(rot_step, which=["q"])
    with pytest.raises(fgopt.FgoptError, match="branches on a symbolic value"):
        generate(branching, cache=False)
    with pytest.raises(fgopt.FgoptError, match="annotated Rot3"):
        generate(wrong_return, cache=False)
    with pytest.raises(fgopt.FgoptError, match="method must be one of"):
        generate(rot_step, method="numeric")


def test_generate_stays_in_its_layer():
    """generate's modules import nothing above fgopt.symbolic (errors, manifolds allowed)."""
    root = Path(fgopt.__file__).parent / "symbolic"
    for name in ("generated.py", "_generate_source.py", "_generate_values.py"):
        tree = ast.parse((root / name).read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.level >= 2:
                top = (node.module or "").split(".")[0]
                assert top in {"errors", "manifolds", ""}, f"{name} imports ..{node.module}"
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                assert not node.module.startswith("fgopt."), f"{name} imports {node.module}"
    assert Matrix.shaped(3, 1) is V3
