"""Noise models and robust losses (``fgopt.noise.Diagonal.sigmas(...)``, ``fgopt.noise.Huber``)."""

from .factors.noise import Barron as Barron
from .factors.noise import Cauchy as Cauchy
from .factors.noise import Diagonal as Diagonal
from .factors.noise import Gaussian as Gaussian
from .factors.noise import GemanMcClure as GemanMcClure
from .factors.noise import Huber as Huber
from .factors.noise import Isotropic as Isotropic
from .factors.noise import NoiseModel as NoiseModel
from .factors.noise import RobustLoss as RobustLoss
from .factors.noise import Tukey as Tukey
from .factors.noise import Unit as Unit
