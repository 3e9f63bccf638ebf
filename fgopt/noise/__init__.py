"""Noise models and robust losses (``fgopt.noise.Diagonal.sigmas(...)``, ``fgopt.noise.Huber``).

A layer of its own, just above the manifolds: the compiled problem whitens and reweights with
these, so the core needs them without importing the factor library.
"""

from .models import Barron as Barron
from .models import Cauchy as Cauchy
from .models import Diagonal as Diagonal
from .models import Gaussian as Gaussian
from .models import GemanMcClure as GemanMcClure
from .models import Huber as Huber
from .models import Isotropic as Isotropic
from .models import NoiseModel as NoiseModel
from .models import RobustLoss as RobustLoss
from .models import Tukey as Tukey
from .models import Unit as Unit

#: The public names (each has an entry in the API reference: tests/test_docs_reference.py).
__all__ = ["Barron", "Cauchy", "Diagonal", "Gaussian", "GemanMcClure", "Huber", "Isotropic",
           "NoiseModel", "RobustLoss", "Tukey", "Unit"]
