"""Noise models whiten with R^T R = information; robust losses give IRLS weights rho'(t)/t."""

import numpy as np
import pytest

from fgopt import noise
from fgopt.errors import DimensionMismatchError, NonFiniteError, NotPositiveDefiniteError
from fgopt.noise.robust import rho_and_weight


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


@pytest.mark.parametrize("code,shape", [(1, 0.0), (2, 0.0), (3, 0.0), (4, 0.0)] +
                         [(5, a) for a in (2.0, 1.0, 0.5, 0.0, -2.0, -7.5)])
@pytest.mark.parametrize("t", [0.1, 0.9, 1.7, 5.0])
def test_weight_is_derivative_of_rho_over_t(code, shape, t):
    """w(t) = rho'(t) / t, checked by central differences of rho; rho ~ t^2/2 near 0."""
    k = 1.345
    h = 1e-6
    rho_p, _ = rho_and_weight(code, k, shape, (t + h) ** 2)
    rho_m, _ = rho_and_weight(code, k, shape, (t - h) ** 2)
    _, w = rho_and_weight(code, k, shape, t * t)
    assert np.isclose((rho_p - rho_m) / (2 * h) / t, w, rtol=1e-5, atol=1e-9)
    small, _ = rho_and_weight(code, k, shape, 1e-8)
    assert np.isclose(small, 0.5e-8, rtol=1e-4)


@pytest.mark.parametrize("t", [0.0, 0.3, 1.0, 4.0, 30.0])
def test_barron_special_cases(t):
    """Barron's loss is L2 at alpha=2, pseudo-Huber at 1, Cauchy (scale sqrt(2) k) at 0 and
    Geman-McClure (scale 2 k) at -2, also exactly at the epsilon-handled alphas 0 and 2, and
    continuous through them."""
    k, s = 1.7, t * t
    k2 = k * k
    expect = {2.0: (0.5 * s, 1.0),
              1.0: (k2 * (np.sqrt(1 + s / k2) - 1), 1 / np.sqrt(1 + s / k2)),
              0.0: (k2 * np.log1p(s / (2 * k2)), 1 / (1 + s / (2 * k2))),
              -2.0: (2 * k2 * s / (s + 4 * k2), (4 * k2 / (s + 4 * k2)) ** 2)}
    for alpha, (rho, w) in expect.items():
        got = rho_and_weight(5, k, alpha, s)
        assert np.allclose(got, (rho, w), rtol=1e-12, atol=1e-300), alpha
        # continuous through the epsilon-handled points
        for da in (1e-7, -1e-7):
            near = rho_and_weight(5, k, alpha + da, s)
            assert np.allclose(near, (rho, w), rtol=1e-5, atol=1e-12), (alpha, da)


def test_barron_epsilon_form_has_removable_singularities():
    """The SymForce treatment, checked symbolically (paper Sec. VI-B): with b = |a-2| + eps and
    d = a + eps sign_no_zero(a), rho(a) at a = 0 and a = 2 has the limit of the exact loss, and
    so does the IRLS weight (the derivative in s)."""
    sp = pytest.importorskip("sympy")
    import fgopt.symbolic as fs
    from fgopt.symbolic import _sym

    a, s = sp.symbols("alpha s", real=True)
    k = sp.Rational(3, 2)
    eps = fs.epsilon
    b = sp.Abs(a - 2) + eps
    d = a + eps * _sym.snz(a)
    rho = k**2 * b / d * ((s / (k**2 * b) + 1) ** (d / 2) - 1)
    s0 = sp.Rational(7, 3)
    for a0 in (0, 2):
        rep = fs.check_removable_singularity(rho.subs(s, s0), a, a0, orders=0)
        assert rep.ok, rep.messages
        weight = 2 * sp.diff(rho, s)
        rep = fs.check_removable_singularity(weight.subs(s, s0), a, a0, orders=0)
        assert rep.ok, rep.messages
        # and the numeric kernel agrees with the limit
        limit = float(rep.values[0][1][0])
        assert np.isclose(rho_and_weight(5, float(k), float(a0), float(s0))[1], limit, rtol=1e-12)


def test_barron_in_a_problem_matches_its_loss():
    """A factor with a Barron loss costs rho(|r|) in the compiled problem as in the loss object."""
    base = noise.Isotropic.sigma(2, 0.5)
    loss = noise.Barron(1.2, 0.5, base)
    e = np.array([3.0, -1.0])
    t2 = float(np.sum((e / 0.5) ** 2))
    assert np.isclose(loss.cost(e), rho_and_weight(5, 1.2, 0.5, t2)[0])
    assert "alpha=0.5" in repr(loss)
    with pytest.raises(NonFiniteError):
        noise.Barron(1.0, np.nan)


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
