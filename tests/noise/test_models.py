"""Noise models refuse shapes and numbers they cannot be: an FgoptError naming what is wrong
(``Isotropic.sigma(0, s)`` used to raise NumPy's IndexError, ``Diagonal.sigmas([])`` gave a
zero-dimensional model, ``Huber("a", ...)`` a ValueError from ``float``)."""

from __future__ import annotations

import numpy as np
import pytest

from fgopt.errors import FgoptError
from fgopt.noise import Barron, Cauchy, Diagonal, Gaussian, Huber, Isotropic, Unit


@pytest.mark.parametrize("dim", [0, -1, 2.5, True, "3"])
def test_isotropic_and_unit_need_a_positive_integer_dimension(dim):
    """Dimensions below 1 and non-integers are refused by both constructors."""
    with pytest.raises(FgoptError, match="dimension must be an integer >= 1"):
        Isotropic.sigma(dim, 1.0)
    with pytest.raises(FgoptError, match="dimension must be an integer >= 1"):
        Unit(dim)


def test_empty_models_are_refused():
    """No sigma, or a 0 x 0 square root information, is not a noise model."""
    with pytest.raises(FgoptError, match="at least one number"):
        Diagonal.sigmas([])
    with pytest.raises(FgoptError, match="at least 1 x 1"):
        Gaussian(np.zeros((0, 0)))


@pytest.mark.parametrize("make", [lambda v: Huber(v, Unit(2)), lambda v: Cauchy(v, Unit(2)),
                                  lambda v: Barron(1.0, v, Unit(2))])
def test_robust_parameters_must_be_numbers(make):
    """A string where a loss parameter goes names the parameter."""
    with pytest.raises(FgoptError, match="must be a number, got 'a'"):
        make("a")


def test_valid_models_still_build():
    """NumPy integer dimensions and the usual constructors are unaffected."""
    assert Isotropic.sigma(np.int64(3), 0.5).dim == 3
    assert Unit(2).dim == 2 and Diagonal.sigmas([0.1, 0.2]).dim == 2
