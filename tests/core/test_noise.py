"""Noise models whiten with R^T R = information; robust losses give IRLS weights rho'(t)/t."""

import numpy as np
import pytest

from fgopt import noise
from fgopt.errors import DimensionMismatchError, NonFiniteError, NotPositiveDefiniteError
from fgopt.factors.robust import rho_and_weight


def test_constructors_agree():
    s = np.array([0.1, 0.2, 0.5])
    C = np.diag(s ** 2)
    for model in (noise.Diagonal.sigmas(s), noise.Gaussian.from_covariance(C),
                  noise.Gaussian.from_information(np.linalg.inv(C)),
                  noise.Diagonal.variances(s ** 2), noise.Diagonal.precisions(1 / s ** 2)):
        R = model.sqrt_information
        assert np.allclose(R.T @ R, np.linalg.inv(C))
        assert np.allclose(np.triu(R), R)
        assert np.allclose(model.covariance, C)
    assert np.allclose(noise.Isotropic.sigma(2, 0.5).sqrt_information, 2 * np.eye(2))
    assert noise.Unit(4).is_unit and noise.Unit(4).dim == 4


def test_full_covariance_whitening():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(4, 4))
    C = A @ A.T + np.eye(4)
    m = noise.Gaussian.from_covariance(C)
    e = rng.normal(size=4)
    assert np.isclose(m.cost(e), 0.5 * e @ np.linalg.solve(C, e))


@pytest.mark.parametrize("bad", [np.diag([1.0, -1.0]), np.array([[1.0, 2.0], [2.0, 1.0]]),
                                 np.array([[1.0, 0.5], [0.0, 1.0]])])
def test_not_positive_definite_is_refused(bad):
    with pytest.raises(NotPositiveDefiniteError):
        noise.Gaussian.from_covariance(bad)
    with pytest.raises(NotPositiveDefiniteError):
        noise.Gaussian.from_information(bad)


def test_bad_sigmas():
    with pytest.raises(NotPositiveDefiniteError):
        noise.Diagonal.sigmas([1.0, 0.0])
    with pytest.raises(NonFiniteError):
        noise.Diagonal.sigmas([1.0, np.nan])
    with pytest.raises(DimensionMismatchError):
        noise.Gaussian.from_covariance(np.ones((2, 3)))


@pytest.mark.parametrize("code", [1, 2, 3, 4])
@pytest.mark.parametrize("t", [0.1, 0.9, 1.7, 5.0])
def test_weight_is_derivative_of_rho_over_t(code, t):
    """w(t) = rho'(t) / t, checked by central differences of rho; rho ~ t^2/2 near 0."""
    k = 1.345
    h = 1e-6
    rho_p, _ = rho_and_weight(code, k, (t + h) ** 2)
    rho_m, _ = rho_and_weight(code, k, (t - h) ** 2)
    _, w = rho_and_weight(code, k, t * t)
    assert np.isclose((rho_p - rho_m) / (2 * h) / t, w, rtol=1e-5, atol=1e-9)
    small, _ = rho_and_weight(code, k, 1e-8)
    assert np.isclose(small, 0.5e-8, rtol=1e-4)


def test_robust_loss_cost_uses_whitened_norm():
    base = noise.Isotropic.sigma(2, 0.5)
    loss = noise.Huber(1.0, base)
    e = np.array([3.0, 4.0])  # whitened norm 10
    assert np.isclose(loss.cost(e), 1.0 * 10 - 0.5)
    assert np.isclose(loss.weight(e), 0.1)


def test_general_sqrt_information_is_made_upper_triangular():
    """Kernels read only R's upper triangle: a full R is replaced by the triangular factor of
    the same information, so the cost is unchanged."""
    rng = np.random.default_rng(2)
    R = rng.normal(size=(3, 3)) + 3 * np.eye(3)
    m = noise.Gaussian.from_sqrt_information(R)
    assert np.allclose(np.tril(m.sqrt_information, -1), 0.0)
    assert np.allclose(m.information, R.T @ R)
    e = rng.normal(size=3)
    assert np.isclose(m.cost(e), 0.5 * np.sum((R @ e) ** 2))
