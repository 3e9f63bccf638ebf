"""The fgopt error family: every error fgopt raises derives from :class:`FgoptError`.

Messages say what went wrong, where (factor, key, file:line) and what to do about it.
"""

from __future__ import annotations


class FgoptError(Exception):
    """Root of every error fgopt raises on purpose.

    Example:

    >>> try:
    ...     fgopt.Variables().at(key('x', 1))
    ... except fgopt.FgoptError as e:
    ...     print(type(e).__name__)
    ...
    KeyNotFoundError
    """


class FgoptWarning(UserWarning):
    """Something a result depends on that the user probably did not intend (e.g. initial values
    no factor uses); the run goes on, and the result records it."""


class KeyNotFoundError(FgoptError, KeyError):
    """A key is used that the `Variables` (or the graph) does not hold."""

    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0]) if self.args else ""


class DuplicateKeyError(FgoptError):
    """`Variables.add` was called for a key that is already present."""


class DimensionMismatchError(FgoptError, ValueError):
    """A value, measurement, noise model or Jacobian has the wrong size."""


class FgoptIndexError(FgoptError, IndexError):
    """An index is out of range (e.g. an entry of a symbolic vector)."""


class NotPositiveDefiniteError(FgoptError, ValueError):
    """A covariance / information matrix, or a linear system, is not positive definite.

    ``variable``: when a factorization of H failed at a known pivot, the index (in the
    problem's variable order) of the variable it belongs to, else None."""

    def __init__(self, message: str = "", variable: int | None = None):
        super().__init__(message)
        self.variable = variable


class NonFiniteError(FgoptError, ValueError):
    """A NaN or inf appeared in a value, residual or Jacobian."""


class EmptyProblemError(FgoptError, ValueError):
    """The graph has no factors, or no variables to optimize."""


class BackendUnavailableError(FgoptError, ImportError):
    """A linear-solver backend was selected but its library is missing."""


class ManifoldError(FgoptError, TypeError):
    """A value's type is not a known manifold (register it, or give it dim/local/retract)."""


class ManifoldDeclarationError(FgoptError, ValueError):
    """An ``@fgopt.manifold`` declaration is wrong (sizes, non-finite retract, ``local`` not the
    inverse of ``retract`` to first order); the message names the method and the failing check."""


class FileFormatError(FgoptError, ValueError):
    """A data file is malformed; the message names the file and line."""

    def __init__(self, message: str, path: str | None = None, line: int | None = None):
        where = ""
        if path is not None:
            where = f"{path}:{line}: " if line is not None else f"{path}: "
        super().__init__(where + message)
        self.path = path
        self.line = line


class CheiralityError(NonFiniteError):
    """A point is behind a camera (or outside a lens model's valid region): its projection is
    undefined. A subclass of :class:`NonFiniteError` because inside the optimizer a trial step
    that causes it is rejected exactly like a step that produces NaN."""


class CalibrationError(FgoptError, ValueError):
    """A camera calibration is invalid (e.g. a non-positive focal length), or an iterative
    ``calibrate`` did not converge."""


class TriangulationError(FgoptError, ValueError):
    """A landmark cannot be triangulated: fewer than two views, or a rank-deficient system
    (the views' rays are parallel)."""


#: Optional extras: import name -> (extra, what it adds). ``pip install 'fgopt[<extra>]'``.
EXTRAS = {"sksparse": ("cholmod", "CHOLMOD (scikit-sparse; needs SuiteSparse)")}


def have_extra(module: str) -> bool:
    """Whether the optional dependency ``module`` (see :data:`EXTRAS`) is importable."""
    import importlib.util

    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def missing_extra(module: str, feature: str) -> BackendUnavailableError:
    """The error for ``feature`` needing the absent optional dependency ``module``: it names the
    extra and the pip command that adds it."""
    extra, what = EXTRAS[module]
    return BackendUnavailableError(
        f"{feature} needs {what}, which is not installed: pip install 'fgopt[{extra}]' "
        f"(on Debian/Ubuntu first apt-get install libsuitesparse-dev), or use fgopt's own "
        f"solvers (the default)")

#: The public names (each has an entry in the API reference: tests/test_docs_reference.py).
__all__ = ["FgoptError", "FgoptWarning", "KeyNotFoundError", "DuplicateKeyError",
           "DimensionMismatchError", "FgoptIndexError", "NotPositiveDefiniteError",
           "NonFiniteError", "EmptyProblemError", "BackendUnavailableError", "ManifoldError",
           "ManifoldDeclarationError", "FileFormatError", "CheiralityError", "CalibrationError",
           "TriangulationError", "EXTRAS", "have_extra", "missing_extra"]
