"""``FactorBatch``: many factors of one kernel, stored as arrays (no Python object per factor).

Readers of large files (BAL, g2o) add factors with ``FactorGraph.add_batch`` so loading is
vectorized; the compiled problem groups individual kernel factors into the same form. A batch
holds, for ``n`` instances of ``kernel``:

- ``keys``: ``(n, k)`` int64 variable keys, in ``kernel.arg_kinds`` order;
- ``constants``: ``(n, c)`` float64 kernel constants (measurements);
- ``sqrt_information``: ``(n, r, r)`` square-root information, or ``None`` for unit noise;
- ``loss_code`` / ``loss_param`` / ``loss_shape``: one robust loss for the whole batch (code
  ``0`` = none; ``loss_shape`` is Barron's alpha), see
  :mod:`fgopt.noise.robust`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import DimensionMismatchError, NonFiniteError
from .factors.base import KernelFactor
from .factors.kernel import FactorKernel
from .noise.models import NoiseModel, Unit, base_noise, loss_code_and_param
from .key import Key


@dataclass(eq=False)
class FactorBatch:
    kernel: FactorKernel
    keys: np.ndarray
    constants: np.ndarray
    sqrt_information: np.ndarray | None
    loss_code: int = 0
    loss_param: float = 0.0
    loss_shape: float = 0.0
    #: Optional labels for error messages: a list of strings per row, or ``(path, lines)`` with
    #: an int array of line numbers (formatted "path:line" on demand; cheap for big files).
    origin: "list[str] | tuple[str, np.ndarray] | None" = field(default=None, repr=False)

    def __post_init__(self):
        k = self.kernel
        self.keys = np.ascontiguousarray(self.keys, dtype=np.int64)
        n = self.keys.shape[0]
        if self.keys.ndim != 2 or self.keys.shape[1] != len(k.arg_kinds):
            raise DimensionMismatchError(
                f"{k.name} batch: keys must be (n, {len(k.arg_kinds)}), got {self.keys.shape}")
        self.constants = np.ascontiguousarray(self.constants, dtype=float).reshape(n, k.num_constants)
        if not np.all(np.isfinite(self.constants)):
            row = int(np.nonzero(~np.all(np.isfinite(self.constants), axis=1))[0][0])
            raise NonFiniteError(f"{k.name} batch: constants of row {self._where(row)} have NaN/inf")
        if self.sqrt_information is not None:
            R = np.ascontiguousarray(self.sqrt_information, dtype=float)
            r = k.residual_dim
            if R.shape == (r, r):
                R = np.broadcast_to(R, (n, r, r)).copy()
            if R.shape != (n, r, r):
                raise DimensionMismatchError(
                    f"{k.name} batch: sqrt_information must be ({n}, {r}, {r}), got {R.shape}")
            if not np.all(np.isfinite(R)):
                raise NonFiniteError(f"{k.name} batch: sqrt_information has NaN/inf")
            self.sqrt_information = R

    def _where(self, row: int) -> str:
        if self.origin is None:
            return f"row {row}"
        if isinstance(self.origin, tuple):
            path, lines = self.origin
            return f"{path}:{int(lines[row])}"
        return self.origin[row]

    def __len__(self) -> int:
        return self.keys.shape[0]

    def loss_of(self, i: int):
        from .noise import models as noise

        base: NoiseModel = (Unit(self.kernel.residual_dim) if self.sqrt_information is None
                            else noise.Gaussian(self.sqrt_information[i]))
        return noise.robust_loss(self.loss_code, self.loss_param, self.loss_shape, base)

    def factor(self, i: int) -> KernelFactor:
        """Materialize row ``i`` as an ordinary factor object."""
        return KernelFactor(self.kernel, [Key(int(k)) for k in self.keys[i]], self.constants[i],
                            self.loss_of(i))


def batch_from_factors(kernel: FactorKernel, factors: list[KernelFactor],
                       keys: np.ndarray | None = None) -> FactorBatch:
    """Stack kernel factors that share ``kernel`` and a loss kind into one batch (``keys``:
    their ``(n, k)`` keys, when the caller has them already)."""
    n = len(factors)
    if keys is None:
        k = len(kernel.arg_kinds)
        # fromiter over the flat keys: ~4x faster than np.array on tuples of Key (an int subclass)
        keys = np.fromiter((q for f in factors for q in f.keys), dtype=np.int64,
                           count=n * k).reshape(n, k)
    consts = (np.array([f.constants for f in factors], dtype=float).reshape(n, kernel.num_constants))
    code, param, shape = loss_code_and_param(factors[0].loss)
    R = _stacked_sqrt_information([base_noise(f.loss) for f in factors])
    # The factors and their noise models checked their values when they were made (finite
    # constants of the kernel's size, finite square R): the batch is assembled as it is,
    # without FactorBatch's checks of arrays from outside.
    b = object.__new__(FactorBatch)
    b.kernel, b.keys, b.constants, b.sqrt_information = kernel, keys, consts, R
    b.loss_code, b.loss_param, b.loss_shape, b.origin = code, param, shape, None
    return b


def _stacked_sqrt_information(noises: list[NoiseModel]) -> np.ndarray | None:
    """``(n, r, r)`` square-root information of ``noises``, or None when all are unit. Factors
    often share one noise model object: its R is then broadcast, not gathered n times."""
    first = noises[0]
    if all(m is first for m in noises):
        if first.is_unit:
            return None
        return np.repeat(first.sqrt_information[None], len(noises), axis=0)
    if all(m.is_unit for m in noises):
        return None
    return np.array([m.sqrt_information for m in noises], dtype=float)
