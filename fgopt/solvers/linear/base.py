"""The ``LinearSolver`` protocol: analyze the pattern once, then factorize and solve each step.

Solvers receive H as the data array of the lower-triangular CSC pattern
(:class:`fgopt.structure.HessianPattern`); damping is already added to its diagonal.
``factorize`` raises :class:`~fgopt.errors.NotPositiveDefiniteError` when H (+ damping) is not
positive definite, which LM answers by raising its damping. The direct solvers test every pivot
against its diagonal entry of H (:data:`PIVOT_TOLERANCE`), so a singular H (a free gauge, a
variable no factor constrains) raises, whatever the sign of the rounding noise left in its pivot.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from ...errors import FgoptError, NotPositiveDefiniteError
from ...key import key_str
from ...structure import DENSE_MAX_SIZE, DENSE_MIN_FILL, HessianPattern

#: A Cholesky pivot ``d_j`` (``L_jj^2``, or ``D_jj`` of ``L D L^T``) is accepted when
#: ``d_j > PIVOT_TOLERANCE * H_jj``. ``d_j / H_jj`` is the fraction of coordinate j's information
#: that the coordinates eliminated before it do not explain (scale invariant); rounding leaves
#: ~1e-16..1e-14 in a direction H does not constrain (a free gauge), while a weakly anchored chain
#: of 10,000 poses keeps ~1e-10. The incremental smoother's default ``pivot_tolerance``.
PIVOT_TOLERANCE = 1e-12


def pivot_failure(solver: str, var_offset: np.ndarray, var_dim: np.ndarray, column: int,
                  tolerance: float = PIVOT_TOLERANCE) -> NotPositiveDefiniteError:
    """The error for the failed pivot of H's scalar ``column``: it names the variable index
    (``variable`` attribute; :func:`describe_indefinite` turns it into a key)."""
    # (offsets follow the elimination order, not the variable index)
    v = int(np.argmax((var_offset <= column) & (column < var_offset + var_dim)))
    return NotPositiveDefiniteError(
        f"{solver}: H is not positive definite: the pivot of tangent coordinate "
        f"{column - int(var_offset[v])} of variable #{v} is not above {tolerance:g} x its "
        "diagonal entry", variable=v)


def describe_indefinite(exc: NotPositiveDefiniteError, var_keys: np.ndarray, what: str,
                        advice: str) -> NotPositiveDefiniteError:
    """``exc`` restated for the user: ``what`` failed because the information matrix is singular
    or indefinite at the named variable (GTSAM's ``IndeterminateSystemException`` names one key
    too), then ``advice``."""
    v = getattr(exc, "variable", None)
    where = (f" at {key_str(int(var_keys[v]))} (that variable, or a group it belongs to, is "
             "not constrained by its factors)" if v is not None and 0 <= v < len(var_keys)
             else "")
    return NotPositiveDefiniteError(
        f"{what}: the information matrix H is singular or indefinite{where}; {advice} "
        f"[{exc}]", variable=v)


@runtime_checkable
class LinearSolver(Protocol):
    name: str

    def analyze(self, pattern: HessianPattern) -> None:
        """Symbolic work that depends only on the pattern (orderings, elimination trees)."""

    def factorize(self, H_data: np.ndarray) -> None:
        """Numeric factorization of H with this pattern."""

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """Solve ``H x = rhs`` with the last factorization."""


def choose_linear_solver(pattern: HessianPattern | None, backend: str = "numba") -> str:
    """The backend ``"auto"`` picks for a problem's pattern (measured choices, see README).

    Small systems (at most ``DENSE_MAX_SIZE`` unknowns): dense Cholesky when H is at least
    ``DENSE_MIN_FILL`` full or the process still runs small work on NumPy (no numba compile
    yet: :func:`fgopt._jit.numpy_budget_left`), else the block Cholesky. Larger ones: fgopt's block supernodal
    Cholesky, which factors 1.4-5x faster than CHOLMOD supernodal (its OpenMP loops serial, as
    fgopt calls it) on every pose graph and the full BA system measured
    (``benchmarks/factorization.py``); BA-shaped problems go to the Schur complement.
    On the NumPy backend (``backend="numpy"``: a solve without numba) CHOLMOD when the
    ``fgopt[cholmod]`` extra is installed, else qdldl's LDL^T (a wheel; no numba, no compile).
    """
    from ...errors import have_extra

    if pattern is None:
        return "cholmod" if have_extra("sksparse") else "block"
    if pattern.size <= DENSE_MAX_SIZE:  # small: no Schur complement (nor its ordering)
        from ..._jit import numpy_budget_left

        full = 2 * pattern.nnz - pattern.size  # nnz: the upper triangle's entries
        # LAPACK while the process rents (fgopt._jit): the block solver's analysis and
        # factorization are ~30 s of numba compilation on a fresh install
        sparse = full < DENSE_MIN_FILL * pattern.size ** 2
        return "block" if sparse and backend != "numpy" and not numpy_budget_left() else "dense"
    if backend == "numpy":
        return "cholmod" if have_extra("sksparse") else "ldlt"
    from ._schur_layout import is_ba_shaped

    if is_ba_shaped(pattern):
        return "schur"
    return "block"


def make_linear_solver(name: "str | LinearSolver", pattern: HessianPattern | None = None,
                       backend: str = "numba", **options) -> LinearSolver:
    """``"auto" | "block" | "cholmod" | "schur[_dense|_sparse|_pcg]" | "ldlt" | "pcg" | "dense"``
    (or a solver object, returned as is).

    ``"auto"`` chooses from the problem's ``pattern`` and ``backend`` (:func:`choose_linear_solver`).

    >>> from fgopt.solvers import make_linear_solver
    >>> type(make_linear_solver("dense")).__name__, type(make_linear_solver("ldlt")).__name__
    ('DenseCholeskySolver', 'LDLTSolver')
    >>> sample = fgopt.datasets.manhattan_2d(num_poses=20, seed=0)
    >>> fgopt.optimize(sample.graph, sample.initial, linear_solver=make_linear_solver("ldlt")).success
    True
    """
    if not isinstance(name, str):
        return name
    if name == "auto":
        name = choose_linear_solver(pattern, backend)
    if name == "cholmod":
        from .cholmod import CholmodSolver

        return CholmodSolver(**options)
    if name in ("ldlt", "qdldl"):
        from .ldlt import LDLTSolver

        return LDLTSolver(**options)
    if name in ("pcg", "cg"):
        from .pcg import PCGSolver

        return PCGSolver(**options)
    if name in ("block", "block_cholesky"):
        from .block_cholesky import BlockCholeskySolver

        return BlockCholeskySolver(**options)
    if name in ("schur", "schur_dense", "schur_sparse", "schur_pcg"):
        from .schur import SchurSolver

        return SchurSolver(reduced="auto" if name == "schur" else name[len("schur_"):], **options)
    if name == "dense":
        from .dense import DenseCholeskySolver

        from ..._jit import numpy_budget_left

        # numba's kernels once the process's NumPy-twin budget is spent, the rule small factor
        # batches follow (fgopt._jit): a small solve in a fresh script imports no numba
        options.setdefault("numba", backend != "numpy" and not numpy_budget_left())
        return DenseCholeskySolver(**options)
    raise FgoptError(
        f"unknown linear solver {name!r}: choose 'auto', 'block', 'cholmod', 'schur', "
        "'schur_dense', 'schur_sparse', 'schur_pcg', 'ldlt', 'pcg' or 'dense'")
