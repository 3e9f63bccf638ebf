"""``@fgopt.manifold``: declarations, their generated kernels and cache, Product, bad input."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import fgopt
from fgopt.errors import DimensionMismatchError, FgoptError, ManifoldDeclarationError
from fgopt.manifolds import SO2, SO3, ops_for
from fgopt.symbolic import V1, V2, V3, Rot3, Scalar, atan2, cos, sin, sqrt, where
from fgopt.symbolic.declare import decorator as D

REPO = Path(__file__).resolve().parents[2]


@fgopt.manifold
class Circle:
    """The unit circle as a unit complex number ``[c, s]`` (SO(2) by hand)."""

    storage_dim = 2
    dim = 1

    def identity():
        return V2(1, 0)

    def angle(x):
        return atan2(x[1], x[0])

    def retract(x, d):
        c, s = cos(d[0]), sin(d[0])
        return V2(x[0] * c - x[1] * s, x[0] * s + x[1] * c)

    def local(x, y):
        return V1(atan2(x[0] * y[1] - x[1] * y[0], x[0] * y[0] + x[1] * y[1]))

    def normalize(x):
        return x.storage / x.storage.norm(0)


@fgopt.manifold
class NavLike(fgopt.Product(Rot3, V3, V3, names=("attitude", "position", "velocity"))):
    """Attitude, position, velocity as the product SO(3) x R^3 x R^3."""


def test_circle_matches_so2():
    """A declared circle equals the built-in SO2 (an independent implementation): retract,
    local, batched kernels, storage_D_tangent, accessors, repr."""
    rng = np.random.default_rng(0)
    C = Circle.Value
    for _ in range(10):
        t, d = rng.uniform(-np.pi, np.pi), rng.uniform(-2, 2)
        x, g = C([np.cos(t), np.sin(t)]), SO2(t)
        np.testing.assert_allclose(x.retract([d]).to_storage(), g.retract([d]).to_storage(),
                                   atol=1e-14)
        y, h = C([np.cos(t + d), np.sin(t + d)]), SO2(t + d)
        np.testing.assert_allclose(x.local(y), g.local(h), atol=1e-12)
        assert abs(x.angle() - t) < 1e-12 and isinstance(x.angle(), float)
        np.testing.assert_allclose(x.storage_D_tangent(), [[-np.sin(t)], [np.cos(t)]],
                                   atol=1e-14)
    X = np.array([C([np.cos(t), np.sin(t)]).to_storage() for t in (0.1, 2.0, -3.0)])
    dl = np.array([[0.3], [-1.0], [2.5]])
    kind = C.batch_kind()
    assert kind.name == "Circle" and kind.dim == 1 and kind.storage_dim == 2
    R = kind.retract(X, dl)
    np.testing.assert_allclose(kind.local(X, R), dl, atol=1e-12)
    assert repr(C()) == "Circle([1., 0.])"
    assert C([3.0, 4.0]).equals(C([0.6, 0.8]))  # storage is normalized on construction


def test_value_type_protocol():
    """Values are immutable, registered (ops_for), compare with equals, and reject bad input."""
    x = Circle.Value([0.0, 2.0])
    np.testing.assert_allclose(x.to_storage(), [0.0, 1.0])
    assert ops_for(x).batch_kind(x) is Circle.Value.batch_kind()
    assert Circle.Value.symbolic_type() is Circle and Circle.Value.dim() == 1
    with pytest.raises(AttributeError):
        x.foo = 1
    with pytest.raises(DimensionMismatchError):
        Circle.Value([1.0, 0.0, 0.0])
    with pytest.raises(FgoptError):
        Circle.Value([np.nan, 1.0])
    with pytest.raises(DimensionMismatchError):
        x.retract([0.1, 0.2])
    with pytest.raises(FgoptError):
        x.local(SO2())


def test_symbolic_twin():
    """The twin is a symbolic type: storage symbols, accessors, retract/local expressions,
    storage_D_tangent derived from retract (epsilon limits taken)."""
    x = Circle.symbolic("x")
    assert [str(s) for s in x.to_storage()] == ["x_0", "x_1"]
    assert Circle.storage_dim() == 2 and Circle.dim() == 1
    D = x.storage_D_tangent()
    assert D.shape == (2, 1) and str(D[0, 0]) == "-x_1" and str(D[1, 0]) == "x_0"
    assert x.local(x.retract([0])).shape == (1, 1)
    with pytest.raises(TypeError):
        x.local(V2(1, 0))


def test_product_matches_independent_implementation():
    """Product(Rot3, V3, V3): retract = (R Exp(w), p + dp, v + dv) and local its inverse,
    against scipy's rotations; accessors give SO3 / arrays; storage_D_tangent block diagonal."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(1)
    N = NavLike.Value
    assert N.dim() == 9 and N.storage_dim() == 10
    for _ in range(5):
        q = Rotation.random(random_state=rng).as_quat()
        p, v = rng.normal(size=3), rng.normal(size=3)
        x = N(np.concatenate([q, p, v]))
        d = rng.normal(size=9)
        y = x.retract(d)
        want_q = (Rotation.from_quat(q) * Rotation.from_rotvec(d[:3])).as_quat()
        got = y.to_storage()
        assert min(np.abs(got[:4] - want_q).max(), np.abs(got[:4] + want_q).max()) < 1e-12
        np.testing.assert_allclose(got[4:], np.concatenate([p + d[3:6], v + d[6:]]),
                                   atol=1e-12)
        np.testing.assert_allclose(x.local(y), d, atol=1e-10)
        assert isinstance(x.attitude(), SO3)
        np.testing.assert_allclose(x.position(), p)
        S = x.storage_D_tangent()
        np.testing.assert_allclose(S[4:, 3:], np.eye(6), atol=1e-15)
        assert np.abs(S[:4, 3:]).max() == 0 and np.abs(S[4:, :3]).max() == 0
    assert repr(N()).startswith("NavLike(attitude=SO3(qw=1.000")
    assert NavLike.Value.position_dim() == 3


def test_product_in_a_factor_solves():
    """A product twin in an @fgopt.factor signature (accessor in the body) batches and solves:
    a GPS-like position factor + priors pull the states where they should go."""
    @fgopt.factor
    def position_of(x: NavLike, measured: V3) -> V3:
        return x.position() - measured

    rng = np.random.default_rng(2)
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    noise = fgopt.noise.Isotropic.sigma(3, 0.1)
    for i in range(5):
        k = fgopt.key("x", i)
        truth = rng.normal(size=3)
        graph.add(position_of(k, truth, loss=noise))
        graph.add(fgopt.PriorFactor(k, NavLike.Value(), fgopt.noise.Isotropic.sigma(9, 10.0)))
        initial.add(k, NavLike.Value().retract(rng.normal(size=9)))
    result = fgopt.optimize(graph, initial)
    assert result.success
    f0 = graph[0]
    assert f0.kernel.arg_kinds == (NavLike.Value.batch_kind(),)
    for i in range(5):
        np.testing.assert_allclose(result.values.at(fgopt.key("x", i)).position(),
                                   graph[2 * i].constants, atol=1e-3)


def test_where_selects_without_branches():
    """where(cond, a, b): 0/1 indicator of <=, <, >=, > and &, |, ~; derivative of the branch."""
    import sympy as sp

    x, y = sp.symbols("x y", real=True)
    e = where((x <= y) & ~(x < -1), x * x, 2 * y)
    f = sp.lambdify((x, y), e)
    assert f(0.5, 1.0) == 0.25 and f(2.0, 1.0) == 2.0 and f(-2.0, 1.0) == 2.0
    assert sp.lambdify((x, y), where(x <= y, 1, 0))(1.0, 1.0) == 1.0  # ties are <=
    assert sp.lambdify((x, y), where(x < y, 1, 0))(1.0, 1.0) == 0.0
    de = sp.diff(where(x >= 0, x**2, -x), x).replace(lambda a: isinstance(a, sp.DiracDelta),
                                                     lambda a: 0)
    assert sp.lambdify(x, de)(3.0) == 6.0 and sp.lambdify(x, de)(-3.0) == -1.0
    v = where(x <= y, V2(x, 1), V2(0, y))
    assert v.shape == (2, 1)


# ------------------------------------------------------------------------------ bad input
def _declare(*parts: str, name: str = "Bad"):
    """Declare a manifold from pieces of a class body (no cache) and return it."""
    ns = {"V1": V1, "V2": V2, "V3": V3, "sqrt": sqrt, "cos": cos, "sin": sin, "atan2": atan2,
          "fgopt": fgopt}
    body = "\n".join(textwrap.dedent(p) for p in parts)
    src = f"@fgopt.manifold(cache=False)\nclass {name}:\n" + textwrap.indent(body, "    ")
    exec(compile(src, f"<test {name}>", "exec"), ns)  # noqa: S102
    return ns[name]


_CIRCLE_RETRACT = """
    def retract(x, d):
        c, s = cos(d[0]), sin(d[0])
        return V2(x[0] * c - x[1] * s, x[0] * s + x[1] * c)
"""


def test_declaration_local_not_inverse_of_retract():
    """local(x, retract(x, d)) = 2 d: rejected at declaration, naming the check."""
    with pytest.raises(ManifoldDeclarationError, match="not d to first order"):
        _declare("""
            storage_dim = 2
            dim = 1
            def identity():
                return V2(1, 0)
            def local(x, y):
                return V1(2 * atan2(x[0] * y[1] - x[1] * y[0], x[0] * y[0] + x[1] * y[1]))
        """, _CIRCLE_RETRACT)


def test_declaration_wrong_sizes():
    """Storage of the wrong size from identity / retract / local names the method."""
    base = "storage_dim = 2\ndim = 1\n"
    local = "def local(x, y):\n    return V1(0)\n"
    with pytest.raises(ManifoldDeclarationError, match=r"identity\(\) returned 3"):
        _declare(base + "def identity():\n    return V3(1, 0, 0)\n" + local, _CIRCLE_RETRACT)
    with pytest.raises(ManifoldDeclarationError, match=r"retract\(x, d\) returned 3"):
        _declare(base + local + "def retract(x, d):\n    return V3(x[0], x[1], d[0])\n")
    with pytest.raises(ManifoldDeclarationError, match=r"local\(x, y\) returned 2 tangent"):
        _declare(base + "def local(x, y):\n    return V2(0, 0)\n", _CIRCLE_RETRACT)
    with pytest.raises(ManifoldDeclarationError, match="dim 3 exceeds storage_dim"):
        _declare("storage_dim = 2\ndim = 3\n" + local, _CIRCLE_RETRACT)
    with pytest.raises(ManifoldDeclarationError, match="storage_dim must be a positive int"):
        _declare("storage_dim = 2.5\ndim = 1\n" + local, _CIRCLE_RETRACT)
    with pytest.raises(ManifoldDeclarationError, match=r"define local"):
        _declare("storage_dim = 2\ndim = 1\n", _CIRCLE_RETRACT)


def test_declaration_retract_not_finite_at_identity():
    """sin(t)/t with the raw norm is 0/0 at d = 0: rejected, naming retract and the identity."""
    with pytest.raises(ManifoldDeclarationError, match="retract is not finite at the identity"):
        _declare("""
            storage_dim = 3
            dim = 3
            def identity():
                return V3(0, 0, 0)
            def retract(x, d):
                t = sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2, epsilon=0)
                return x.storage + d * (sin(t) / t)
            def local(x, y):
                return y.storage - x.storage
        """)


def test_declaration_branching_on_symbols_is_explained():
    """A Python `if` on a symbolic value fails with advice, not a SymPy traceback."""
    with pytest.raises(ManifoldDeclarationError, match="without Python branches"):
        _declare("""
            storage_dim = 1
            dim = 1
            def retract(x, d):
                return [x[0] + d[0] if x[0] > 0 else x[0] - d[0]]
            def local(x, y):
                return [y[0] - x[0]]
        """)


PoseLike = fgopt.manifold(fgopt.Product(SO3, V3, float, names=("R", "t", "s")),
                          name="PoseLike")


def test_product_of_numeric_types_by_name():
    """Product(SO3, V3, float) maps numeric types to their symbolic twins; the call form
    fgopt.manifold(Product(...), name=...) declares a picklable module-level type."""
    import pickle

    assert PoseLike._COMPONENTS == (Rot3, V3, Scalar) and PoseLike.dim() == 7
    x = PoseLike.Value().retract(np.arange(7) * 0.1)
    np.testing.assert_allclose(x.t(), [0.3, 0.4, 0.5])
    assert x.s() == pytest.approx(0.6) and isinstance(x.R(), SO3)
    y = pickle.loads(pickle.dumps(x))
    assert type(y) is PoseLike.Value and y.equals(x, 1e-15)
    assert fgopt.Unit3 is fgopt.symbolic.Unit3.Value  # numeric at the top, symbolic below


def test_product_bad_components():
    with pytest.raises(ManifoldDeclarationError, match="is not a component type"):
        fgopt.Product(Rot3, dict)
    with pytest.raises(ManifoldDeclarationError, match="2 names for 3 components"):
        fgopt.Product(Rot3, V3, Scalar, names=("a", "b"))


# ------------------------------------------------------------------------------ cache
def test_declaration_loads_from_cache_without_sympy():
    """A second process finds the generated module: declaring and solving with the manifold
    imports no SymPy and derives nothing."""
    code = textwrap.dedent("""
        import sys
        import numpy as np
        import fgopt
        from fgopt.symbolic.declare import decorator as D
        from tests.symbolic.test_declare import Circle
        assert D.STATS["derived"] == 0 and D.STATS["loaded"] >= 2, D.STATS
        x = Circle.Value([0.0, 1.0]).retract([0.5])
        y = Circle.Value.batch_kind().retract(np.array([[1.0, 0.0]]), np.array([[0.5]]))
        assert np.allclose(x.angle(), np.pi / 2 + 0.5) and np.allclose(y[0], [np.cos(.5), np.sin(.5)])
        assert "sympy" not in sys.modules, "sympy imported"
        print("ok")
    """)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0 and "ok" in out.stdout, out.stderr[-3000:]


def test_declaration_key_follows_the_code():
    """The declaration key hashes the methods: the same body gives the same key (the cached
    module is reused), an edited method a new one (it is derived again)."""
    body = """
        storage_dim = 2
        dim = 1
        def identity():
            return V2(1, 0)
        def local(x, y):
            return V1(atan2(x[0] * y[1] - x[1] * y[0], x[0] * y[0] + x[1] * y[1]))
    """
    a = _declare(body, _CIRCLE_RETRACT, name="Keyed")
    b = _declare(body, _CIRCLE_RETRACT, name="Keyed")
    c = _declare(body, _CIRCLE_RETRACT.replace("d[0]", "(d[0] + 0)"), name="Keyed")
    assert a._KEY == b._KEY != c._KEY
    assert b is a  # declaring the same code again (a re-run notebook cell) gives the same type
    assert D.DECLARED[c._KEY] is c


# ------------------------------------------------------------------- NumPy twins of the kernels
def _declared(name: str):
    if name in ("Circle", "NavLike"):
        return {"Circle": Circle, "NavLike": NavLike}[name]
    from fgopt.symbolic import geometry

    return getattr(geometry, name)


@pytest.mark.parametrize("name", ["Circle", "NavLike", "Unit3", "OrientedPlane3", "SE23"])
def test_numpy_twins_equal_numba_kernels(name):
    """Each generated kernel (retract, local, storage_D_tangent, normalize) has a NumPy twin
    (Unit3's `where` / `Abs` basis included) whose numbers equal the numba kernel's, and a small
    batch runs the twin: the numba kernel is not compiled by it."""
    kind = _declared(name).Value.batch_kind()
    ns = kind.retract.__globals__
    rng = np.random.default_rng(11)
    n = 64
    identity = np.asarray(ns["IDENTITY"], dtype=float)
    x = ns["normalize_batch"](identity + 0.3 * rng.normal(size=(n, identity.size))) \
        if "normalize_batch" in ns else identity + 0.3 * rng.normal(size=(n, identity.size))
    d = 0.5 * rng.normal(size=(n, ns["DIM"]))
    d[:4] *= 1e-9  # near the identity: the series / epsilon branches
    y = kind.retract(x, d)
    assert not ns["_retract_kernel"].compiled and not ns["_local_kernel"].compiled
    for op, args in [("retract", (x, d)), ("local", (x, y)), ("storage_D_tangent", (x,)),
                     ("normalize", (x,))]:
        if f"_{op}_kernel" not in ns:
            continue
        assert f"_{op}_numpy" in ns, f"{name}.{op} has no NumPy twin"
        shape = {"retract": x.shape, "local": d.shape,
                 "storage_D_tangent": (n, x.shape[1], d.shape[1]), "normalize": x.shape}[op]
        twin, compiled = np.empty(shape), np.empty(shape)
        with np.errstate(all="ignore"):
            ns[f"_{op}_numpy"](*args, twin)
        ns[f"_{op}_kernel"](*args, compiled)
        np.testing.assert_allclose(twin, compiled, rtol=1e-12, atol=1e-14, err_msg=f"{op}")


def test_declaring_and_solving_imports_no_numba(tmp_path):
    """A new declaration and the first solve of a small graph over it (empty kernel cache) run
    on NumPy twins and plain Python: numba is never imported in that process."""
    code = textwrap.dedent("""
        import sys
        import numpy as np
        import fgopt
        from fgopt import key
        from fgopt.symbolic import V2, atan2, cos, sin

        @fgopt.manifold
        class TwinCircle:
            storage_dim = 2
            dim = 1
            def identity():
                return V2(1, 0)
            def retract(x, d):
                c, s = cos(d[0]), sin(d[0])
                return V2(x[0] * c - x[1] * s, x[0] * s + x[1] * c)
            def local(x, y):
                return fgopt.symbolic.V1(atan2(x[0] * y[1] - x[1] * y[0],
                                               x[0] * y[0] + x[1] * y[1]))

        @fgopt.factor
        def twin_circle_between(a: TwinCircle, b: TwinCircle, angle: fgopt.symbolic.V1) \\
                -> fgopt.symbolic.V1:
            return a.local(b) - angle

        graph, initial = fgopt.FactorGraph(), fgopt.Variables()
        noise = fgopt.noise.Isotropic.sigma(1, 0.1)
        for i in range(5):
            graph.add(twin_circle_between(key("c", i), key("c", i + 1), np.array([0.2]),
                                          loss=noise))
        graph.add(fgopt.PriorFactor(key("c", 0), TwinCircle.Value([1.0, 0.0]), noise))
        for i in range(6):
            initial.add(key("c", i), TwinCircle.Value([np.cos(0.25 * i), np.sin(0.25 * i)]))
        r = fgopt.optimize(graph, initial)
        assert r.success and r.final_cost < 1e-16, r
        assert "numba" not in sys.modules, "numba imported"
        print("ok")
    """)
    env = dict(os.environ, PYTHONPATH=str(REPO), FGOPT_CACHE_DIR=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", code], check=False, cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and "ok" in out.stdout, out.stderr[-3000:]
