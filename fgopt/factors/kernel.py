"""The batched-kernel contract between factor types and the compiled problem.

A :class:`FactorKernel` evaluates *n* instances of one factor type at once, from gathered
storage rows of its variables and a per-instance constants array (measurements and other
fixed inputs). It returns the *unwhitened* residual and the tangent-space Jacobian; the
problem applies the noise model's square-root information and robust (IRLS) weights in its own
numba scatter kernel, so kernels stay independent of noise and loss.

Shapes (``r`` = residual dim, ``s_i`` / ``d_i`` = storage / tangent dim of argument ``i``,
``c`` = ``num_constants``, ``D = sum(d_i)``)::

    residual(args, consts)  -> res (n, r)
    linearize(args, consts) -> (res (n, r), jac (n, r, D))

``args`` is a tuple of ``(n, s_i)`` float64 arrays, one per variable argument in
``arg_kinds`` order; ``consts`` is ``(n, c)`` float64 (``c`` may be 0). The Jacobian columns of
argument ``i`` are ``jac[:, :, off_i:off_i + d_i]`` with ``off_i = sum(d_j for j < i)``, and they
are derivatives with respect to the argument's tangent space *as the argument's manifold
defines retract* (``x (+) delta``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..errors import FgoptError
from ..manifolds.base import BatchKind

ResidualFn = Callable[[tuple, np.ndarray], np.ndarray]
LinearizeFn = Callable[[tuple, np.ndarray], "tuple[np.ndarray, np.ndarray]"]


@dataclass(frozen=True)
class CompiledCall:
    """How generated numba code calls a kernel's linearization, as source text.

    The driver imports ``function`` from the module named ``module`` (already in
    ``sys.modules``: the kernel's own module) and calls
    ``function(<prefix>a_0, ..., a_k, consts, res, jac)`` when ``fills`` (writing ``res (n, r)``
    and ``jac (n, r, D)``), else ``res, jac = function(<prefix>a_0, ..., a_k, consts<suffix>)``.

    ``hessian``: the function adds the batch's ``J^T J`` / ``J^T r`` itself (a kernel whose
    Hessian is cheaper than its Jacobian, e.g. a smart factor's Schur complement), called as
    ``cost = function(<prefix>storage, rows, consts<suffix>, toff, H, g, cost)``: every argument
    of one kind, its storage rows ``storage[rows[i, j]]``, tangent offsets ``toff (n, k)``, a
    dense ``H (N, N)`` (both triangles) and ``g``; unit noise, no robust loss. It returns ``cost``
    plus the batch's cost.

    ``prefix`` and ``suffix`` are pasted into numba code, where a constant argument (``3``,
    ``True``) is typed as a literal and compiles the callee (and everything it passes it to)
    once more, beside the general path's compile for ``int64`` / ``bool``; write
    ``np.int64(3)``, ``np.bool_(True)`` to share the general path's machine code.
    ``specialized``: ``function`` takes a calibration model's or Lie group's integer id first
    (``prefix`` passes it, as ``np.int64``), and the driver calls its copy specialized for
    this id (:func:`fgopt._jit.specialized_copy`: the one the general path's
    :func:`fgopt._jit.specialize` entry runs).
    """

    module: str
    function: str
    prefix: str = ""
    suffix: str = ""
    fills: bool = False
    hessian: bool = False
    specialized: int | None = None


@dataclass(frozen=True, eq=False)
class FactorKernel:
    """Batched residual / Jacobian evaluator of one factor type and variable pattern.

    Kernels compare by identity: factors sharing a kernel object (and loss kind) are batched
    together.

    Example: a hand-written kernel of ``x - m`` on R^1 (NumPy here; the built-in kernels are
    numba functions), used by two factors:

    >>> from fgopt.factors import FactorKernel, KernelFactor
    >>> from fgopt.manifolds import vector_kind
    >>> def residual(args, consts):                  # args: ((n, 1),), consts: (n, 1)
    ...     return args[0] - consts
    ...
    >>> def linearize(args, consts):
    ...     return residual(args, consts), np.ones((len(consts), 1, 1))
    ...
    >>> kernel = FactorKernel("offset", (vector_kind(1),), 1, 1, residual, linearize)
    >>> graph = fgopt.FactorGraph([KernelFactor(kernel, [key('x', 0)], np.array([m]))
    ...                            for m in (2.0, 4.0)])
    >>> initial = fgopt.Variables().add(key('x', 0), np.array([5.0]))
    >>> np.round(fgopt.optimize(graph, initial).values.at(key('x', 0)), 6)   # the mean
    array([3.])
    """

    name: str
    arg_kinds: tuple[BatchKind, ...]
    residual_dim: int
    num_constants: int
    residual: ResidualFn = field(repr=False)
    linearize: LinearizeFn = field(repr=False)
    source: str = field(default="", repr=False)
    #: Why this kernel may return NaN on purpose (e.g. a point behind a camera), appended to the
    #: optimizer's error when the initial estimate produces one.
    nonfinite_hint: str = field(default="", repr=False)
    #: ``(function, args)`` that returns this kernel again in any process; how a kernel pickles
    #: (the receiving process rebuilds or loads it; compiled code is never shipped). The function
    #: must return one object per distinct ``args`` (kernels compare by identity).
    recipe: tuple | None = field(default=None, repr=False)
    #: Clamped functions in the residual (dicts: function, low, high, where, code), and
    #: ``clamp_arguments(args, consts) -> (n, len(clamps))`` evaluating their arguments.
    clamps: tuple = field(default=(), repr=False)
    clamp_arguments: ResidualFn | None = field(default=None, repr=False)
    #: True when ``residual`` / ``linearize`` evaluate every batch with NumPy (no numba) inside
    #: :func:`fgopt._jit.numpy_mode`: generated kernels with NumPy twins. A problem runs on the
    #: NumPy backend only when all its kernels have this (``Problem(backend=)``).
    numpy_twin: bool = field(default=False, repr=False)
    #: ``linearize`` on numba for a caller that guarantees its arguments (a tuple of
    #: C-contiguous float64 ``(n, s_i)`` arrays and ``(n, c)`` float64 constants, ``n >= 1``):
    #: no shape checks and no NumPy twin, whatever ``n``. The compiled problem's hot path (1.5-2
    #: us less per call, what small batches spend) and online updates; ``None``: ``linearize``.
    trusted_linearize: LinearizeFn | None = field(default=None, repr=False)
    #: ``(storages, rows, consts, toff, pos, col_shift, H_data, g, weights, cost) -> cost``: adds
    #: the batch's ``J^T J`` / ``J^T r`` straight into the compiled problem's H and g on numba
    #: (``storages[j][rows[:, j]]``: argument ``j``'s storage rows; ``toff`` / ``pos`` /
    #: ``col_shift``: the scatter map of :func:`fgopt._assembly.scatter_batch`), for kernels
    #: whose ``J^T J`` has structure the generic scatter cannot see (smart factors: a
    #: block-diagonal ``F`` under a rank-3 projection). Used for unit noise without a robust
    #: loss; the same sums as ``linearize`` + scatter, up to rounding. ``None``: the scatter.
    scatter_hessian: Callable | None = field(default=None, repr=False)
    #: How compiled code calls this kernel's numba linearization (:class:`CompiledCall`): what
    #: lets :mod:`fgopt.solvers.small` run a whole small problem in one compiled driver.
    #: ``None``: the driver cannot call it (the problem takes the general path).
    compiled_call: CompiledCall | None = field(default=None, repr=False)

    def __reduce__(self):
        if self.recipe is None:
            raise FgoptError(f"kernel {self.name!r} cannot be pickled: it was made without a "
                             "recipe (FactorKernel(..., recipe=(function, args)) says how "
                             "another process gets it)")
        return self.recipe

    @property
    def tangent_dim(self) -> int:
        return sum(k.dim for k in self.arg_kinds)

    @property
    def arg_offsets(self) -> tuple[int, ...]:
        offs, o = [], 0
        for k in self.arg_kinds:
            offs.append(o)
            o += k.dim
        return tuple(offs)


def module_trusted_linearize(raw: Callable, residual_dim: int, tangent_dim: int) -> LinearizeFn:
    """:attr:`FactorKernel.trusted_linearize` of a generated kernel module, from its numba
    ``_linearize_kernel(*args, consts, res, jac)`` (``res (n, r)``, ``jac (n, r, D)``)."""

    def linearize(args: tuple, consts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = consts.shape[0]
        res = np.empty((n, residual_dim))
        jac = np.empty((n, residual_dim, tangent_dim))
        raw(*args, consts, res, jac)
        return res, jac

    # for callers that allocate ``res`` / ``jac`` themselves (the incremental smoother)
    linearize.raw = raw
    linearize.dims = (residual_dim, tangent_dim)
    return linearize
