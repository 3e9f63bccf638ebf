"""``fgopt.check_manifold(M)``: numeric checks of a declared manifold, as a readable report.

Runs on the compiled batched kernels and the per-value functions of the generated module, at
the identity (or a normalized random storage) and at points reached from it by ``retract`` with
steps of 0.3, 1 and 2.5 (or at the values you pass). Rows of the report:

* ``retract(x, 0) = x``;
* ``local(x, retract(x, d)) = d`` to first order (``|d| = 1e-4``: error / |d| below 1e-4) and
  near 0 (``|d| <= 0.3``: error / |d|^2 below 10, exact inverses give ~1e-15);
* ``retract(x, local(x, y)) = y`` for ``y`` near ``x`` (``|local(y, y')|``);
* ``storage_D_tangent`` against central differences of ``retract``;
* ``d local(a, b) / da`` and ``/ db`` (the tangent-space Jacobians factors get, derived by
  SymPy) against central differences through ``retract``;
* normalization: ``retract`` returns normalized storage; ``normalize`` is idempotent and maps
  storage perturbed by ``e`` to a point within ``10 |e|`` of where it started;
* the batched kernels agree with the per-value functions.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...errors import FgoptError
from .checks import STEP, Functions, fd_storage_D_tangent


@dataclass
class CheckRow:
    """One check: the worst error over the points, its tolerance, and where it was worst."""

    check: str
    error: float
    tolerance: float
    where: str = ""

    @property
    def ok(self) -> bool:
        return bool(np.isfinite(self.error) and self.error <= self.tolerance)


@dataclass
class ManifoldReport:
    """What :func:`check_manifold` found; ``ok`` if every row passed; ``str()`` is a table."""

    name: str
    num_points: int
    rows: list[CheckRow] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return all(r.ok for r in self.rows)

    def raise_if_failed(self) -> ManifoldReport:
        if not self.ok:
            raise FgoptError(f"check_manifold({self.name}) failed:\n{self}")
        return self

    def __str__(self) -> str:
        head = (f"check_manifold({self.name}): {self.num_points} points, "
                + ("all checks passed" if self.ok else
                   f"{sum(not r.ok for r in self.rows)} FAILED"))
        w = max(len(r.check) for r in self.rows)
        lines = [head, f"  {'check':<{w}}  {'max error':>10}  {'tolerance':>9}  ok"]
        for r in self.rows:
            lines.append(f"  {r.check:<{w}}  {r.error:10.2e}  {r.tolerance:9.1e}  "
                         + ("yes" if r.ok else f"NO  (worst at {r.where})"))
        return "\n".join(lines)

    __repr__ = __str__


class _SpecFunctions(Functions):
    def __init__(self, spec: Any):
        self.n, self.dim = spec.storage_dim, spec.dim
        self._retract, self._local = spec.retract_one, spec.local_one
        self._sdt, self._normalize = spec.storage_D_tangent_one, spec.normalize_one
        self.identity = None if spec.identity is None else np.array(spec.identity, dtype=float)


def _twin_of(M: Any) -> type:
    from .decorator import is_declared

    if is_declared(M):
        return M
    spec = getattr(M, "_spec", None) or getattr(type(M), "_spec", None)
    if spec is not None and is_declared(spec.twin):
        return spec.twin
    raise FgoptError(f"check_manifold: {M!r} is not a manifold declared with @fgopt.manifold")


def _fmt(x: np.ndarray) -> str:
    return np.array2string(np.asarray(x), precision=4, suppress_small=True, separator=", ")


def _local_jacobians(twin: type):
    """Python function ``(a storage, b storage) -> (J_a, J_b)`` of ``local``'s tangent
    Jacobians, derived as factor kernels derive them (:mod:`fgopt.symbolic.linearize`)."""
    from ..codegen import python_function
    from ..linearize import linearization_program

    a, b = twin.symbolic("a"), twin.symbolic("b")
    prog = linearization_program(list(a.local(b)), [a, b])
    fn = python_function(a.to_storage() + b.to_storage(), prog)
    d = twin._DIM

    def jac(x: np.ndarray, y: np.ndarray):
        J = np.array(fn(*x.tolist(), *y.tolist())["jac"], dtype=float).reshape(d, 2 * d)
        return J[:, :d], J[:, d:]

    return jac


def check_manifold(M: Any, points: Any = None, seed: int = 0,
                   jacobians: bool = True) -> ManifoldReport:
    """Check a declared manifold numerically; returns a :class:`ManifoldReport`.

    Args:
        M: the declaration (twin class), its ``.Value`` class or a value.
        points: values or storage vectors to check at (default: see the module docstring).
        seed: random directions.
        jacobians: also derive ``local``'s tangent Jacobians with SymPy and check them.
    """
    twin = _twin_of(M)
    spec = twin.Value._spec
    kind = twin.Value.batch_kind()
    f = _SpecFunctions(spec)
    rng = np.random.default_rng(seed)
    if points is None:
        x0 = f.base_point(rng)
        pts = [x0] + [f.retract(x0, s * u / np.linalg.norm(u))
                      for s in (0.3, 1.0, 2.5) for u in rng.normal(size=(2, f.dim))]
    else:
        pts = [np.asarray(p.to_storage() if hasattr(p, "to_storage") else p, dtype=float)
               for p in points]
        pts = [f.normalize(p) for p in pts]
    rows: dict[str, list] = {}

    def note(name: str, err: float, tol: float, x: np.ndarray) -> None:
        err = float(err) if np.isfinite(err) else np.inf
        cur = rows.setdefault(name, [0.0, tol, ""])
        if not err <= cur[0]:
            cur[0], cur[2] = err, f"x = {_fmt(x)}"

    jac = _local_jacobians(twin) if jacobians else None
    eye = np.eye(f.dim)
    with np.errstate(all="ignore"):
        for x in pts:
            note("retract(x, 0) = x", np.max(np.abs(f.retract(x, np.zeros(f.dim)) - x)), 1e-12, x)
            for _ in range(3):
                u = rng.normal(size=f.dim)
                u /= np.linalg.norm(u)
                d = 1e-4 * u
                e = np.linalg.norm(f.local(x, f.retract(x, d)) - d) / 1e-4
                note("local(x, retract(x, d)) = d to first order (|d| = 1e-4)", e, 1e-4, x)
                worst = 0.0
                for s in (0.3, 0.1, 0.01):
                    e2 = np.linalg.norm(f.local(x, f.retract(x, s * u)) - s * u) / s**2
                    worst = max(worst, e2) if np.isfinite(e2) else np.inf
                note("local(x, retract(x, d)) = d near 0 (error / |d|^2, |d| <= 0.3)", worst,
                     10.0, x)
                y = f.retract(x, 0.3 * u)
                v = 0.2 * rng.normal(size=f.dim)
                z = f.retract(y, v)
                back = f.retract(y, f.local(y, z))
                note("retract(y, local(y, z)) = z (z near y)", np.linalg.norm(f.local(z, back)),
                     1e-9, y)
                if jac is not None:
                    Ja, Jb = jac(y, z)
                    Na = np.stack([(f.local(f.retract(y, STEP * eye[j]), z)
                                    - f.local(f.retract(y, -STEP * eye[j]), z)) / (2 * STEP)
                                   for j in range(f.dim)], axis=1)
                    Nb = np.stack([(f.local(y, f.retract(z, STEP * eye[j]))
                                    - f.local(y, f.retract(z, -STEP * eye[j]))) / (2 * STEP)
                                   for j in range(f.dim)], axis=1)
                    sa = max(1.0, float(np.max(np.abs(Na))))
                    sb = max(1.0, float(np.max(np.abs(Nb))))
                    note("d local(a, b) / da (derived) vs central differences",
                         np.max(np.abs(Ja - Na)) / sa, 1e-6, y)
                    note("d local(a, b) / db (derived) vs central differences",
                         np.max(np.abs(Jb - Nb)) / sb, 1e-6, y)
                r = f.retract(x, 0.5 * u)
                note("retract output is normalized (normalize(r) = r)",
                     np.max(np.abs(f.normalize(r) - r)), 1e-12, x)
                noise = 1e-3 * rng.normal(size=f.n)
                p = f.normalize(x + noise)
                note("normalize is idempotent (on perturbed storage)",
                     np.max(np.abs(f.normalize(p) - p)), 1e-12, x)
                note("normalize(x + e) stays near x (|local(x, .)| / |e|)",
                     np.linalg.norm(f.local(x, p)) / np.linalg.norm(noise), 10.0, x)
            D = f.storage_D_tangent(x)
            Dfd = fd_storage_D_tangent(f, x)
            note("storage_D_tangent (derived) vs central differences of retract",
                 np.max(np.abs(D - Dfd)) / max(1.0, float(np.max(np.abs(D)))), 1e-6, x)
        X = np.array(pts)
        Dl = 0.3 * rng.normal(size=(len(pts), f.dim))
        Rb = kind.retract(X, Dl)
        Ro = np.array([f.retract(x, d) for x, d in zip(X, Dl)])
        Lb = kind.local(X, Rb)
        Lo = np.array([f.local(x, r) for x, r in zip(X, Ro)])
        note("batched kernels = per-value functions",
             max(float(np.max(np.abs(Rb - Ro))), float(np.max(np.abs(Lb - Lo)))), 1e-12, X[0])
    report = ManifoldReport(twin.__name__, len(pts))
    report.rows = [CheckRow(k, v[0], v[1], v[2]) for k, v in rows.items()]
    return report
