"""The ``Factor`` base class: a residual over a few variables, with a noise model or loss.

Two ways to make a factor:

* **Slow path (miniSAM style).** Subclass :class:`Factor`, call
  ``super().__init__(keys, dim, loss)``, and implement ``error(values)`` (the unwhitened residual,
  shape ``(dim,)``) and ``jacobians(values)`` (one ``(dim, d_k)`` array per key, derivatives in
  each variable's tangent space). Read variables with ``values.at(k)``. Or subclass
  :class:`~fgopt.factors.numerical.NumericalFactor` and write only ``error``.
* **Fast path.** A :class:`KernelFactor` carries a batched :class:`FactorKernel` and a row of
  constants; the compiled problem evaluates all factors sharing a kernel in one numba call.
  Built-in and ``@fgopt.factor`` factors are kernel factors.

Cost of a factor: ``0.5 * |R e|^2`` with the noise model's square-root information ``R``, or
``rho(|R e|)`` with a robust loss.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..errors import DimensionMismatchError, FgoptError, ManifoldError, NonFiniteError
from ..key import Key, as_key, key_str
from ..manifolds.base import ops_for
from .kernel import FactorKernel
from ..noise.models import Loss, base_noise, resolve_loss


class Factor:
    """A factor over ``keys`` with residual dimension ``dim`` and a noise model / robust ``loss``.

    Example:

    >>> class Offset(fgopt.Factor):
    ...     def __init__(self, k, target, loss=None):
    ...         super().__init__([k], 2, loss)
    ...         self.target = np.asarray(target, float)
    ...     def error(self, values):
    ...         return values.at(self.keys[0]) - self.target
    ...     def jacobians(self, values):
    ...         return [np.eye(2)]
    ...
    >>> values = fgopt.Variables().add(key('p', 0), np.array([1.0, 1.0]))
    >>> Offset(key('p', 0), [0.0, 2.0]).error(values)
    array([ 1., -1.])
    >>> fgopt.check_jacobians([Offset(key('p', 0), [0.0, 2.0])], values).ok
    True
    """

    #: Batched kernel of this factor (fast path); ``None`` for Python factors.
    kernel: FactorKernel | None = None

    def __init__(self, keys: Sequence[int], dim: int, loss: Loss | None = None):
        name = type(self).__name__
        if isinstance(keys, (int, np.integer)) and not isinstance(dim, (int, np.integer)):
            raise FgoptError(
                f"{name}: Factor.__init__ takes (keys, dim, loss), got keys={keys!r} and "
                f"dim={dim!r}: miniSAM's order Factor(dim, keys, loss) swapped? Write "
                f"super().__init__([key, ...], {keys!r}, loss)")
        if isinstance(keys, (int, np.integer, str, bytes)) or not hasattr(keys, "__iter__"):
            raise FgoptError(f"{name}: keys must be a list of keys (e.g. [key('x', 1)]), "
                             f"got {keys!r}")
        self.keys: tuple[Key, ...] = tuple(as_key(k) for k in keys)
        if len(set(self.keys)) != len(self.keys):
            raise FgoptError(f"{name}: repeated key in {list(self.keys)}")
        if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)):
            raise FgoptError(f"{name}: dim must be an int (the residual size), got {dim!r}: "
                             "Factor.__init__ takes (keys, dim, loss)")
        self.dim = int(dim)
        if self.dim <= 0:
            raise DimensionMismatchError(f"{type(self).__name__}: residual dim must be positive")
        self.loss: Loss = resolve_loss(loss, self.dim, self.describe)

    # -- to implement (slow path)
    def error(self, values: Any) -> np.ndarray:
        """Unwhitened residual ``e(x)``, shape ``(dim,)``."""
        raise NotImplementedError(f"{type(self).__name__} must implement error(values)")

    def jacobians(self, values: Any) -> list[np.ndarray]:
        """Tangent-space Jacobians ``de/dx_k``, one ``(dim, d_k)`` array per key."""
        raise NotImplementedError(
            f"{type(self).__name__} must implement jacobians(values), or derive from "
            "NumericalFactor to get central-difference Jacobians")

    # -- derived
    @property
    def noise(self):
        """The Gaussian part of the loss."""
        return base_noise(self.loss)

    def whitened_error(self, values: Any) -> np.ndarray:
        return self.noise.whiten(self.checked_error(values))

    def cost(self, values: Any) -> float:
        """``0.5 |R e|^2`` (or ``rho(|R e|)`` with a robust loss)."""
        return float(self.loss.cost(self.checked_error(values)))

    def checked_error(self, values: Any) -> np.ndarray:
        e = np.asarray(self.error(values), dtype=float).reshape(-1)
        if e.shape[0] != self.dim:
            raise DimensionMismatchError(
                f"{self.describe()}: error() returned {e.shape[0]} values, expected dim {self.dim}")
        if not np.all(np.isfinite(e)):
            raise NonFiniteError(f"{self.describe()}: residual has NaN/inf: {e}")
        return e

    def checked_jacobians(self, values: Any) -> list[np.ndarray]:
        Js = self.jacobians(values)
        if len(Js) != len(self.keys):
            raise DimensionMismatchError(
                f"{self.describe()}: jacobians() returned {len(Js)} blocks for {len(self.keys)} keys")
        out = []
        for k, J in zip(self.keys, Js):
            J = np.asarray(J, dtype=float)
            x = values.at(k)
            d = ops_for(x).dim(x)
            if J.ndim == 1 and self.dim == 1:
                J = J.reshape(1, -1)
            if J.shape != (self.dim, d):
                raise DimensionMismatchError(
                    f"{self.describe()}: Jacobian for {key_str(k)} has shape {J.shape}, "
                    f"expected ({self.dim}, {d})")
            if not np.all(np.isfinite(J)):
                raise NonFiniteError(f"{self.describe()}: Jacobian for {key_str(k)} has NaN/inf")
            out.append(J)
        return out

    def describe(self) -> str:
        keys = ", ".join(key_str(k) for k in self.keys) if hasattr(self, "keys") else "?"
        return f"{type(self).__name__}({keys})"

    def __repr__(self) -> str:
        return f"{self.describe()[:-1]}; dim={self.dim}, loss={self.loss!r})"


class KernelFactor(Factor):
    """A factor evaluated by a batched :class:`FactorKernel` (the fast path).

    ``constants`` are the kernel's per-instance fixed inputs (e.g. a measurement's storage).
    ``error`` / ``jacobians`` on a single instance run the same kernel with ``n = 1``.

    Example: the kernel of a symbolic factor with ``m`` a constant, used directly:

    >>> from fgopt.factors import KernelFactor
    >>> from fgopt.symbolic import V1
    >>> @fgopt.factor
    ... def offset(x: V1, m: V1) -> V1:
    ...     return x - m
    ...
    >>> f = KernelFactor(offset.kernel(["x"]), [key('x', 0)], np.array([2.0]))
    >>> values = fgopt.Variables().add(key('x', 0), np.array([5.0]))
    >>> f.error(values), f.jacobians(values)
    (array([3.]), [array([[1.]])])
    """

    def __init__(self, kernel: FactorKernel, keys: Sequence[int], constants: np.ndarray,
                 loss: Loss | None = None):
        self.kernel = kernel
        if len(keys) != len(kernel.arg_kinds):
            raise DimensionMismatchError(
                f"{kernel.name}: takes {len(kernel.arg_kinds)} variables, got {len(keys)} keys")
        c = np.asarray(constants, dtype=float).reshape(-1)
        if c.shape[0] != kernel.num_constants:
            raise DimensionMismatchError(
                f"{kernel.name}: expected {kernel.num_constants} constants, got {c.shape[0]}")
        if not np.all(np.isfinite(c)):
            raise NonFiniteError(f"{kernel.name}: measurement/constants contain NaN or inf")
        c.setflags(write=False)
        self.constants = c
        super().__init__(keys, kernel.residual_dim, loss)

    def _gather(self, values: Any) -> tuple:
        args = []
        for k, kind in zip(self.keys, self.kernel.arg_kinds):
            x = values.at(k)
            ops = ops_for(x)
            xk = ops.batch_kind(x)
            if xk is not kind:
                raise ManifoldError(
                    f"{self.describe()}: variable {key_str(k)} is a {type(x).__name__} "
                    f"({getattr(xk, 'name', 'no batch kind')}), the factor expects {kind.name}")
            args.append(np.ascontiguousarray(kind.to_storage(x), dtype=float).reshape(1, -1))
        return tuple(args)

    def error(self, values: Any) -> np.ndarray:
        res = self.kernel.residual(self._gather(values), self.constants.reshape(1, -1))
        return np.array(res[0], dtype=float)

    def jacobians(self, values: Any) -> list[np.ndarray]:
        _, jac = self.kernel.linearize(self._gather(values), self.constants.reshape(1, -1))
        return [np.array(jac[0, :, o:o + kind.dim]) for o, kind in
                zip(self.kernel.arg_offsets, self.kernel.arg_kinds)]

    def describe(self) -> str:
        keys = ", ".join(key_str(k) for k in self.keys) if hasattr(self, "keys") else "?"
        return f"{self.kernel.name}({keys})"
