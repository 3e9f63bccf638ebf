"""Declaration-time checks of a declared manifold (numeric, before anything is cached).

Run on the generated plain-Python functions of the declaration (no numba compile), at the
identity (or a normalized random storage when there is none) and at a few points reached from
it by ``retract``. Each failure raises :class:`~fgopt.errors.ManifoldDeclarationError` naming
the method and the check:

1. ``retract(x, 0)`` is finite and equal to ``x`` (normalized) at the identity;
2. ``storage_D_tangent`` (derived from ``retract``) is finite, has rank ``dim`` and matches
   central differences of ``retract``;
3. ``local(x, x) = 0`` and ``local(x, retract(x, d)) = d`` to first order in ``d`` (its
   derivative at ``d = 0``, by central differences, is the identity).

:func:`fgopt.check_manifold` (:mod:`~fgopt.symbolic.declare.report`) runs a longer list on the
compiled kernels and returns a report instead of raising.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...errors import ManifoldDeclarationError

#: Central-difference step and the tolerance of first-order checks (errors are O(h^2)).
STEP = 1e-6
FIRST_ORDER_TOL = 1e-5


def _call(fn: Any, args: list, size: int) -> np.ndarray:
    """``fn(*args)`` as floats; plain Python raises on 0/0 or a math domain error where numba
    kernels give NaN, so those become NaN here too."""
    try:
        return np.array(fn(*args), dtype=float)
    except (ZeroDivisionError, ValueError, OverflowError):
        return np.full(size, np.nan)


class Functions:
    """The per-value functions of a generated manifold module, on float arrays (NaN where the
    code divides by zero or leaves a function's domain)."""

    def __init__(self, ns: Any, storage_dim: int, dim: int):
        self.n, self.dim = storage_dim, dim
        self._retract, self._local = ns.retract_one, ns.local_one
        self._sdt = ns.storage_D_tangent_one
        self._normalize = getattr(ns, "normalize_one", None)
        self.identity = None if ns.IDENTITY is None else np.array(ns.IDENTITY, dtype=float)

    def retract(self, x: np.ndarray, d: np.ndarray) -> np.ndarray:
        return _call(self._retract, x.tolist() + d.tolist(), self.n)

    def local(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return _call(self._local, a.tolist() + b.tolist(), self.dim)

    def storage_D_tangent(self, x: np.ndarray) -> np.ndarray:
        return _call(self._sdt, x.tolist(), self.n * self.dim).reshape(self.n, self.dim)

    def normalize(self, x: np.ndarray) -> np.ndarray:
        if self._normalize is None:
            return np.array(x, dtype=float)
        return _call(self._normalize, x.tolist(), self.n)

    def base_point(self, rng: np.random.Generator) -> np.ndarray:
        if self.identity is not None:
            return self.identity.copy()
        return self.normalize(rng.normal(size=self.n))

    def sample_points(self, rng: np.random.Generator, count: int,
                      scale: float = 0.7) -> list[np.ndarray]:
        """The base point and ``count - 1`` points ``retract(base, random d)``."""
        x0 = self.base_point(rng)
        return [x0] + [self.retract(x0, scale * rng.normal(size=self.dim))
                       for _ in range(count - 1)]


def fd_storage_D_tangent(f: Functions, x: np.ndarray, h: float = STEP) -> np.ndarray:
    cols = []
    for j in range(f.dim):
        e = np.zeros(f.dim)
        e[j] = h
        cols.append((f.retract(x, e) - f.retract(x, -e)) / (2 * h))
    return np.stack(cols, axis=1)


def fd_local_of_retract(f: Functions, x: np.ndarray, h: float = STEP) -> np.ndarray:
    """Central differences of ``d -> local(x, retract(x, d))`` at 0 (the identity if sound)."""
    cols = []
    for j in range(f.dim):
        e = np.zeros(f.dim)
        e[j] = h
        cols.append((f.local(x, f.retract(x, e)) - f.local(x, f.retract(x, -e))) / (2 * h))
    return np.stack(cols, axis=1)


def _fmt(a: np.ndarray) -> str:
    return np.array2string(np.asarray(a), precision=6, suppress_small=True, max_line_width=120)


def check_declaration(twin: type, python_source: str) -> None:
    """Run the checks of the module docstring; raise ManifoldDeclarationError on a failure."""
    import types

    name = twin.__name__
    mod = types.ModuleType(f"<declaration {name}>")
    exec(compile(python_source, f"<generated {name}>", "exec"), mod.__dict__)  # noqa: S102
    f = Functions(mod, twin._STORAGE_DIM, twin._DIM)
    rng = np.random.default_rng(13)
    where = "the identity" if f.identity is not None else "a normalized random storage"
    x0 = f.base_point(rng)
    if not np.all(np.isfinite(x0)):
        raise ManifoldDeclarationError(f"{name}.normalize: not finite at a random storage: "
                                       f"{_fmt(x0)}")
    with np.errstate(all="ignore"):
        r0 = f.retract(x0, np.zeros(f.dim))
    if not np.all(np.isfinite(r0)):
        raise ManifoldDeclarationError(f"{name}.retract is not finite at {where}: retract(x, 0) "
                                       f"= {_fmt(r0)} at x = {_fmt(x0)}; shift norms away from 0 "
                                       "with epsilon (e.g. v.norm() or sqrt(|v|^2 + epsilon**2))")
    if np.max(np.abs(r0 - f.normalize(x0))) > 1e-9 * max(1.0, float(np.max(np.abs(x0)))):
        raise ManifoldDeclarationError(f"{name}.retract: retract(x, 0) = {_fmt(r0)} is not x = "
                                       f"{_fmt(x0)} at {where}")
    with np.errstate(all="ignore"):
        points = f.sample_points(rng, 4)
    for x in points:
        if not np.all(np.isfinite(x)):
            raise ManifoldDeclarationError(f"{name}.retract is not finite: retract(base, d) = "
                                           f"{_fmt(x)} for a random d")
        with np.errstate(all="ignore"):
            D = f.storage_D_tangent(x)
        if not np.all(np.isfinite(D)):
            raise ManifoldDeclarationError(
                f"{name}.storage_D_tangent (d retract(x, v)/dv at v = 0) is not finite at x = "
                f"{_fmt(x)}:\n{_fmt(D)}\nshift norms in retract away from 0 with epsilon")
        if np.linalg.matrix_rank(D, tol=1e-8) < f.dim:
            raise ManifoldDeclarationError(
                f"{name}.storage_D_tangent has rank < dim = {f.dim} at x = {_fmt(x)}: retract "
                f"does not move the storage along every tangent direction\n{_fmt(D)}")
        Dfd = fd_storage_D_tangent(f, x)
        if np.max(np.abs(D - Dfd)) > FIRST_ORDER_TOL * max(1.0, float(np.max(np.abs(D)))):
            raise ManifoldDeclarationError(
                f"{name}.storage_D_tangent disagrees with central differences of retract at "
                f"x = {_fmt(x)}:\n{_fmt(D)}\nvs\n{_fmt(Dfd)}")
        with np.errstate(all="ignore"):
            l0 = f.local(x, x)
        if not np.all(np.isfinite(l0)) or np.max(np.abs(l0)) > 1e-9:
            raise ManifoldDeclarationError(f"{name}.local: local(x, x) = {_fmt(l0)} is not 0 at "
                                           f"x = {_fmt(x)}")
        with np.errstate(all="ignore"):
            J = fd_local_of_retract(f, x)
        if not np.all(np.isfinite(J)) or np.max(np.abs(J - np.eye(f.dim))) > FIRST_ORDER_TOL:
            raise ManifoldDeclarationError(
                f"{name}: local(x, retract(x, d)) is not d to first order at x = {_fmt(x)}: its "
                f"derivative at d = 0 is\n{_fmt(J)}\n(expected the identity): local must invert "
                "retract near d = 0")
