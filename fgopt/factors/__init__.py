"""Factors: the ``Factor`` base (slow path), kernel factors (fast path), noise models, built-ins."""

from .base import Factor as Factor
from .base import KernelFactor as KernelFactor
from .kernel import FactorKernel as FactorKernel
from .library.prior_between import BetweenFactor as BetweenFactor
from .library.prior_between import PriorFactor as PriorFactor
from .numerical import NumericalFactor as NumericalFactor
from .numerical import numerical_jacobian as numerical_jacobian
from .numerical import numerical_jacobians as numerical_jacobians
