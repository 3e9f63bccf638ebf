"""Noise models (whitening) and robust losses (IRLS weights).

A noise model whitens a residual ``e`` by its square-root information ``R`` (upper triangular,
``R^T R = Sigma^-1``): ``r = R e``. The cost of a factor is ``0.5 * |r|^2`` (GTSAM's and Ceres'
definition) or, with a robust loss, ``rho(|r|)`` where ``rho(t) ~ t^2 / 2`` near 0.

Robust losses are applied by iteratively re-weighted least squares: at each linearization the
factor's whitened Jacobian and residual are scaled by ``sqrt(w)`` with ``w = rho'(t) / t``.
Each loss has a small integer ``code`` and one parameter so the compiled problem can evaluate it
inside its numba scatter kernel (see :func:`fgopt.noise.robust.rho_and_weight`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._checks import is_count, number
from ..errors import DimensionMismatchError, NonFiniteError, NotPositiveDefiniteError


class NoiseModel:
    """Gaussian noise with square-root information ``R`` (``dim x dim``, upper triangular).
    The base of :class:`Gaussian`, :class:`Diagonal`, :class:`Isotropic` and :class:`Unit`; a
    residual ``e`` costs ``0.5 |R e|^2``.

    >>> from fgopt.noise import Diagonal
    >>> noise = Diagonal.sigmas([0.1, 0.1, 0.05])
    >>> isinstance(noise, fgopt.noise.NoiseModel), noise.dim
    (True, 3)
    >>> noise.whiten(np.array([0.1, 0.0, 0.05])), noise.cost(np.array([0.1, 0.0, 0.05]))
    (array([1., 0., 1.]), 1.0)
    """

    #: True when R is the identity: whitening can be skipped.
    is_unit: bool = False

    def __init__(self, sqrt_information: np.ndarray):
        R = np.array(sqrt_information, dtype=float)
        if R.ndim != 2 or R.shape[0] != R.shape[1] or R.shape[0] == 0:
            raise DimensionMismatchError(f"square-root information must be square and at least "
                                         f"1 x 1, got shape {R.shape}")
        if not np.all(np.isfinite(R)):
            raise NonFiniteError("noise model has a NaN or inf entry")
        if np.any(np.tril(R, -1) != 0.0):
            # The whitening kernels use only the upper triangle: replace a general R by the
            # upper-triangular factor with the same information R^T R (same cost, same whitening
            # up to a rotation of the residual).
            R = _cholesky(R.T @ R, "information R^T R").T
        R.setflags(write=False)
        self._R = R

    @property
    def dim(self) -> int:
        return self._R.shape[0]

    @property
    def sqrt_information(self) -> np.ndarray:
        return self._R

    @property
    def information(self) -> np.ndarray:
        return self._R.T @ self._R

    @property
    def covariance(self) -> np.ndarray:
        Rinv = np.linalg.inv(self._R)
        return Rinv @ Rinv.T

    def whiten(self, e: np.ndarray) -> np.ndarray:
        return self._R @ np.asarray(e, dtype=float)

    def whiten_jacobian(self, J: np.ndarray) -> np.ndarray:
        return self._R @ np.asarray(J, dtype=float)

    def cost(self, e: np.ndarray) -> float:
        r = self.whiten(e)
        return 0.5 * float(r @ r)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(dim={self.dim})"


class Gaussian(NoiseModel):
    """Full-covariance Gaussian noise.

    Example:

    >>> from fgopt.noise import Gaussian
    >>> g = Gaussian.from_covariance(np.array([[4.0, 0.0], [0.0, 1.0]]))
    >>> np.round(g.whiten(np.array([2.0, 1.0])), 6)
    array([1., 1.])
    """

    @classmethod
    def from_sqrt_information(cls, R: np.ndarray) -> "Gaussian":
        return cls(R)

    @classmethod
    def from_information(cls, information: np.ndarray) -> "Gaussian":
        """Whitening from the information matrix via its Cholesky factor (``I = R^T R``)."""
        L = _cholesky(_symmetric(information, "information"), "information matrix")
        return cls(L.T)

    @classmethod
    def from_covariance(cls, covariance: np.ndarray) -> "Gaussian":
        """Whitening from the covariance: ``R = L^-1`` for ``Sigma = L L^T``."""
        L = _cholesky(_symmetric(covariance, "covariance"), "covariance")
        # Sigma^-1 = L^-T L^-1; store the upper-triangular Cholesky factor of that information so
        # every Gaussian holds an upper-triangular R (the scatter kernel relies on it).
        Linv = np.linalg.inv(L)
        info = Linv.T @ Linv
        return cls.from_information(0.5 * (info + info.T))


class Diagonal(NoiseModel):
    """Independent noise per residual component.

    Pose residuals are in fgopt's tangent order, rotation first: SE(2) ``[theta, x, y]``, SE(3)
    ``[wx, wy, wz, x, y, z]``, Sim(3) ``[w, v, log s]``. GTSAM's Pose2 and miniSAM's SE2 use
    ``[x, y, theta]``, miniSAM's SE3 ``[v, w]``: sigmas copied from them in that order give a
    different model. The named constructors :meth:`pose2`, :meth:`pose3` and :meth:`sim3` take
    sigmas by component and remember them for the repr.

    Example:

    >>> from fgopt.noise import Diagonal
    >>> Diagonal.pose2(x=0.5, y=0.5, theta=0.1).sigma_values
    array([0.1, 0.5, 0.5])
    >>> Diagonal.sigmas([0.1, 0.2]).sqrt_information
    array([[10.,  0.],
           [ 0.,  5.]])
    """

    #: Component names of a pose model (tangent order), for the repr; None for plain sigmas.
    _labels: tuple[str, ...] | None = None
    _constructor: str = ""

    @classmethod
    def sigmas(cls, sigmas) -> "Diagonal":
        s = _positive_vector(sigmas, "sigmas")
        return cls(np.diag(1.0 / s))

    @classmethod
    def pose2(cls, x: float, y: float, theta: float) -> "Diagonal":
        """SE(2) sigmas by component (meters, radians), stored in fgopt's tangent order
        ``[theta, x, y]`` (GTSAM's ``Diagonal.Sigmas([x, y, theta])`` as a Pose2 noise)."""
        return cls._labelled("pose2", ("theta", "x", "y"), [theta, x, y])

    @classmethod
    def pose3(cls, rotation: Any, translation: Any) -> "Diagonal":
        """SE(3) sigmas by component: ``rotation`` (radians, about x, y, z) and ``translation``
        (meters, along x, y, z), each one number or three; tangent order ``[w, v]`` (GTSAM's
        Pose3 order; miniSAM's/Sophus' SE3 is ``[v, w]``)."""
        rot, trans = _three(rotation, "rotation"), _three(translation, "translation")
        return cls._labelled("pose3", ("wx", "wy", "wz", "x", "y", "z"), rot + trans)

    @classmethod
    def sim3(cls, rotation: Any, translation: Any, scale: float) -> "Diagonal":
        """Sim(3) sigmas by component (``scale`` is the sigma of ``log s``); tangent order
        ``[w, v, log s]``."""
        rot, trans = _three(rotation, "rotation"), _three(translation, "translation")
        return cls._labelled("sim3", ("wx", "wy", "wz", "x", "y", "z", "log_s"),
                             rot + trans + [scale])

    @classmethod
    def _labelled(cls, constructor: str, labels: tuple, sigmas: list) -> "Diagonal":
        m = cls.sigmas(sigmas)
        m._labels, m._constructor = labels, constructor
        return m

    def __repr__(self) -> str:
        s = self.sigma_values
        if self._labels is not None:
            parts = ", ".join(f"{n}={v:g}" for n, v in zip(self._labels, s))
            return (f"Diagonal.{self._constructor}(sigmas {parts}; tangent order "
                    f"[{', '.join(self._labels)}])")
        return f"{type(self).__name__}(sigmas=[{', '.join(f'{v:g}' for v in s)}])"

    @classmethod
    def variances(cls, variances) -> "Diagonal":
        return cls.sigmas(np.sqrt(_positive_vector(variances, "variances")))

    @classmethod
    def precisions(cls, precisions) -> "Diagonal":
        return cls(np.diag(np.sqrt(_positive_vector(precisions, "precisions"))))

    @property
    def sigma_values(self) -> np.ndarray:
        return 1.0 / np.diag(self._R)


class Isotropic(Diagonal):
    """The same sigma on every component.

    Example:

    >>> from fgopt.noise import Isotropic
    >>> Isotropic.sigma(3, 0.5).sigma_values
    array([0.5, 0.5, 0.5])
    """

    @classmethod
    def sigma(cls, dim: int, sigma: float) -> "Isotropic":
        s = _positive_vector([sigma], "sigma")[0]
        return cls(np.eye(_dimension(dim)) / s)

    def __repr__(self) -> str:
        return f"Isotropic(dim={self.dim}, sigma={self.sigma_values[0]:g})"


class Unit(Isotropic):
    """Unit noise: the residual is already whitened.

    Example:

    >>> from fgopt.noise import Unit
    >>> Unit(2).whiten(np.array([3.0, 4.0]))
    array([3., 4.])
    """

    is_unit = True

    def __init__(self, dim: int):
        super().__init__(np.eye(_dimension(dim)))

    def __repr__(self) -> str:
        return f"Unit(dim={self.dim})"


def _three(v: Any, name: str) -> list:
    """One number or three, as a list of three floats."""
    a = _positive_vector(v, f"{name} sigmas")
    if a.shape[0] == 1:
        a = np.repeat(a, 3)
    if a.shape[0] != 3:
        raise DimensionMismatchError(f"{name} sigmas: give one number or three, got {a.shape[0]}")
    return a.tolist()


def _dimension(dim: Any) -> int:
    if not is_count(dim) or dim < 1:
        raise DimensionMismatchError(f"noise model dimension must be an integer >= 1, got "
                                     f"{dim!r}")
    return int(dim)


def _number(value: Any, name: str) -> float:
    x = number(value)
    if x is None:
        raise DimensionMismatchError(f"{name} must be a number, got {value!r}")
    return x


def _positive_vector(values, name: str) -> np.ndarray:
    try:
        v = np.atleast_1d(np.asarray(values, dtype=float)).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise DimensionMismatchError(f"{name} must be numbers, got {values!r}") from exc
    if v.size == 0:
        raise DimensionMismatchError(f"{name}: needs at least one number, got {values!r}")
    if not np.all(np.isfinite(v)):
        raise NonFiniteError(f"{name} has a NaN or inf entry: {v}")
    if np.any(v <= 0):
        raise NotPositiveDefiniteError(f"{name} must all be positive, got {v}")
    return v


def _cholesky(M: np.ndarray, what: str) -> np.ndarray:
    try:
        return np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        w = np.linalg.eigvalsh(M)
        raise NotPositiveDefiniteError(
            f"{what} is not positive definite (smallest eigenvalue {w.min():.3g}); "
            "pass a symmetric positive-definite matrix") from None


def _symmetric(M, name: str) -> np.ndarray:
    M = np.array(M, dtype=float)
    if M.ndim != 2 or M.shape[0] != M.shape[1]:
        raise DimensionMismatchError(f"{name} must be a square matrix, got shape {M.shape}")
    if not np.all(np.isfinite(M)):
        raise NonFiniteError(f"{name} has a NaN or inf entry")
    scale = max(1.0, float(np.abs(M).max()))
    if np.abs(M - M.T).max() > 1e-9 * scale:
        raise NotPositiveDefiniteError(f"{name} is not symmetric")
    return 0.5 * (M + M.T)


# ----------------------------------------------------------------------------- robust losses

LOSS_NONE, LOSS_HUBER, LOSS_CAUCHY, LOSS_TUKEY, LOSS_GEMAN_MCCLURE, LOSS_BARRON = 0, 1, 2, 3, 4, 5


class RobustLoss:
    """A robust loss ``rho`` wrapping a Gaussian noise model (``base``).

    ``base=None`` means unit noise of the factor's dimension (filled in by the factor).

    >>> from fgopt.noise import Huber, Isotropic
    >>> loss = Huber(1.0, Isotropic.sigma(2, 0.5))       # threshold 1 on the whitened residual
    >>> isinstance(loss, fgopt.noise.RobustLoss), loss.dim
    (True, 2)
    >>> loss.weight(np.array([0.25, 0.0])), loss.weight(np.array([2.0, 0.0]))   # |R e| = 0.5, 4
    (1.0, 0.25)
    """

    code: int = LOSS_NONE
    #: Second parameter (Barron's ``alpha``); 0 for the one-parameter losses.
    shape: float = 0.0

    def __init__(self, k: float, base: NoiseModel | None = None):
        k = _number(k, f"{type(self).__name__} parameter")
        if not np.isfinite(k) or k <= 0:
            raise NotPositiveDefiniteError(f"{type(self).__name__} parameter must be positive, got {k}")
        self.k = k
        self.base = base

    def with_base(self, base: NoiseModel) -> "RobustLoss":
        return type(self)(self.k, base)

    @property
    def dim(self) -> int:
        return self.base.dim if self.base is not None else -1

    @property
    def sqrt_information(self) -> np.ndarray:
        return self.base.sqrt_information

    def whiten(self, e: np.ndarray) -> np.ndarray:
        return self.base.whiten(e)

    def cost(self, e: np.ndarray) -> float:
        from .robust import rho_and_weight

        r = self.whiten(e)
        rho, _ = rho_and_weight(self.code, self.k, self.shape, float(r @ r))
        return rho

    def weight(self, e: np.ndarray) -> float:
        """IRLS weight ``rho'(t)/t`` at the whitened norm ``t``."""
        from .robust import rho_and_weight

        r = self.whiten(e)
        return rho_and_weight(self.code, self.k, self.shape, float(r @ r))[1]

    def __repr__(self) -> str:
        return f"{type(self).__name__}(k={self.k:g}, base={self.base!r})"


class Huber(RobustLoss):
    """``rho(t) = t^2/2`` for ``|t| <= k``, else ``k |t| - k^2/2``.

    Example:

    >>> from fgopt.noise import Huber, Isotropic
    >>> loss = Huber(1.345, Isotropic.sigma(2, 0.1))
    >>> round(loss.weight(np.array([0.01, 0.0])), 6), round(loss.weight(np.array([1.0, 0.0])), 6)
    (1.0, 0.1345)
    """

    code = LOSS_HUBER


class Cauchy(RobustLoss):
    """``rho(t) = k^2/2 log(1 + t^2/k^2)``.

    Example:

    >>> from fgopt.noise import Cauchy, Unit
    >>> round(Cauchy(1.0, Unit(1)).weight(np.array([2.0])), 6)
    0.2
    """

    code = LOSS_CAUCHY


class Tukey(RobustLoss):
    """``rho(t) = k^2/6 (1 - (1 - t^2/k^2)^3)`` for ``|t| <= k``, else ``k^2/6``.

    Example:

    >>> from fgopt.noise import Tukey, Unit
    >>> loss = Tukey(4.685, Unit(1))
    >>> round(loss.weight(np.array([1.0])), 6), loss.weight(np.array([10.0]))
    (0.910956, 0.0)
    """

    code = LOSS_TUKEY


class GemanMcClure(RobustLoss):
    """``rho(t) = (k^2 t^2 / 2) / (k^2 + t^2)`` (GTSAM's Geman-McClure).

    Example:

    >>> from fgopt.noise import GemanMcClure, Unit
    >>> round(GemanMcClure(1.0, Unit(1)).weight(np.array([1.0])), 6)
    0.25
    """

    code = LOSS_GEMAN_MCCLURE


class Barron(RobustLoss):
    """Barron's general adaptive loss with shape ``alpha`` and scale ``k``:
    ``rho(t) = k^2 |a-2|/a (((t/k)^2/|a-2| + 1)^(a/2) - 1)``; ``alpha`` = 2 is L2, 1
    pseudo-Huber, 0 Cauchy, -2 Geman-McClure (epsilon-safe at 0 and 2, see
    :mod:`fgopt.noise.robust`).

    Example:

    >>> from fgopt.noise import Barron, Unit
    >>> round(Barron(1.0, 2.0, Unit(1)).weight(np.array([3.0])), 6)
    1.0
    >>> round(Barron(1.0, -2.0, Unit(1)).weight(np.array([1.0])), 6)
    0.64
    """

    code = LOSS_BARRON

    def __init__(self, k: float, alpha: float, base: NoiseModel | None = None):
        super().__init__(k, base)
        alpha = _number(alpha, "Barron loss alpha")
        if not np.isfinite(alpha):
            raise NonFiniteError(f"Barron loss alpha must be finite, got {alpha}")
        self.shape = alpha

    @property
    def alpha(self) -> float:
        return self.shape

    def with_base(self, base: NoiseModel) -> "Barron":
        return Barron(self.k, self.shape, base)

    def __repr__(self) -> str:
        return f"Barron(k={self.k:g}, alpha={self.shape:g}, base={self.base!r})"


def robust_loss(code: int, k: float, shape: float = 0.0, base: NoiseModel | None = None) -> Loss:
    """The robust loss of a batch's ``(code, k, shape)`` around ``base`` (``base`` for code 0)."""
    if code == LOSS_NONE:
        return base
    if code == LOSS_BARRON:
        return Barron(k, shape, base)
    cls = {LOSS_HUBER: Huber, LOSS_CAUCHY: Cauchy, LOSS_TUKEY: Tukey,
           LOSS_GEMAN_MCCLURE: GemanMcClure}
    return cls[code](k, base)


Loss = NoiseModel | RobustLoss


_PLAIN_MODELS = (Gaussian, Diagonal, Isotropic, Unit, NoiseModel)


def resolve_loss(loss: Loss | None, dim: int, where) -> Loss:
    """Fill in defaults (``None`` -> unit noise) and check the dimension against ``dim``.

    ``where`` names the factor in errors: a string, or a callable made into one only on error
    (building the description for every factor would cost more than the check).
    """
    if type(loss) in _PLAIN_MODELS and loss.dim == dim:  # the common case, no string work
        return loss
    where = where() if callable(where) else where
    if loss is None:
        return Unit(dim)
    if isinstance(loss, RobustLoss):
        if loss.base is None:
            return loss.with_base(Unit(dim))
        if loss.base.dim != dim:
            raise DimensionMismatchError(
                f"{where}: noise model has dim {loss.base.dim} but the residual has dim {dim}")
        return loss
    if isinstance(loss, NoiseModel):
        if loss.dim != dim:
            raise DimensionMismatchError(
                f"{where}: noise model has dim {loss.dim} but the residual has dim {dim}")
        return loss
    raise DimensionMismatchError(f"{where}: loss must be a noise model or robust loss, got {loss!r}")


def base_noise(loss: Loss) -> NoiseModel:
    return loss.base if isinstance(loss, RobustLoss) else loss


def loss_code_and_param(loss: Loss) -> tuple[int, float, float]:
    """``(code, k, shape)`` of a loss, as batches and numba kernels take it."""
    if isinstance(loss, RobustLoss):
        return loss.code, loss.k, loss.shape
    return LOSS_NONE, 0.0, 0.0
