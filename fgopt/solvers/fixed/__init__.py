"""The fixed formulation (SymForce paper): one generated, whole-problem linearization and a dense
LM, for small problems of symbolic or built-in factors. ``fgopt.optimize(..., formulation="fixed")``
runs it; :mod:`.formulation` is the solver, :mod:`._codegen` writes the problem's module and
:mod:`._llvm` the LLVM intrinsic its numba code calls."""

from .formulation import STATS as STATS
from .formulation import FixedProblem as FixedProblem
from .formulation import compile_fixed as compile_fixed
from .formulation import optimize_fixed as optimize_fixed
