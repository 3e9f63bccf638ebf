"""Incremental smoothing: an iSAM2-class online solver and a fixed-lag smoother.

* :class:`IncrementalSmoother` (``update`` / ``estimate`` / ``marginal`` / ``cost``): iSAM2's
  algorithm on a Bayes tree of dense cliques, with fluid relinearization, wildfire
  back-substitution and batch steps (``smoother.py``);
* :class:`FixedLagSmoother`: keeps the variables of the last ``lag`` seconds and marginalizes
  older ones into a :class:`LinearContainerFactor` on their Markov blanket (``fixed_lag.py``).

Layer: above the core and the solvers (uses the block Cholesky's symbolic steps and BLAS
bindings); nothing below imports it.
"""

from .fixed_lag import FixedLagSmoother as FixedLagSmoother
from .linear_container import LinearContainerFactor as LinearContainerFactor
from .params import IncrementalParams as IncrementalParams
from .params import UpdateResult as UpdateResult
from .smoother import IncrementalSmoother as IncrementalSmoother

#: The public names (each has an entry in the API reference: tests/test_docs_reference.py).
__all__ = ["FixedLagSmoother", "LinearContainerFactor", "IncrementalParams", "UpdateResult",
           "IncrementalSmoother"]
