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
    no factor uses); the run goes on, and the result records it.

    >>> import warnings
    >>> from fgopt.noise import Isotropic
    >>> graph = fgopt.FactorGraph([fgopt.PriorFactor(key('x', 0), fgopt.SE2(), Isotropic.sigma(3, 0.1))])
    >>> initial = fgopt.Variables({key('x', 0): fgopt.SE2(), key('y', 0): fgopt.SE2()})
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     result = fgopt.optimize(graph, initial)
    >>> caught[0].category.__name__, result.unused_keys
    ('FgoptWarning', (y0,))
    """


class KeyNotFoundError(FgoptError, KeyError):
    """A key is used that the `Variables` (or the graph) does not hold.

    >>> fgopt.Variables().at(key('x', 1))
    Traceback (most recent call last):
    fgopt.errors.KeyNotFoundError: ...x1...
    """

    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0]) if self.args else ""


class DuplicateKeyError(FgoptError):
    """`Variables.add` was called for a key that is already present.

    >>> fgopt.Variables().add(key('x', 0), fgopt.SE2()).add(key('x', 0), fgopt.SE2())
    Traceback (most recent call last):
    fgopt.errors.DuplicateKeyError: variable x0 is already present; use update()
    """


class DimensionMismatchError(FgoptError, ValueError):
    """A value, measurement, noise model or Jacobian has the wrong size.

    >>> fgopt.PriorFactor(key('x', 0), fgopt.SE2(), fgopt.noise.Isotropic.sigma(2, 1.0))
    Traceback (most recent call last):
    fgopt.errors.DimensionMismatchError: PriorFactor(x0): noise model has dim 2 but the ...
    """


class FgoptIndexError(FgoptError, IndexError):
    """An index is out of range (e.g. an entry of a symbolic vector).

    >>> fgopt.FactorGraph()[3]
    Traceback (most recent call last):
    fgopt.errors.FgoptIndexError: factor index 3 out of range (0 factors)
    """


class NotPositiveDefiniteError(FgoptError, ValueError):
    """A covariance / information matrix, or a linear system, is not positive definite.

    ``variable``: when a factorization of H failed at a known pivot, the index (in the
    problem's variable order) of the variable it belongs to, else None.

    >>> fgopt.noise.Gaussian.from_covariance(np.array([[1.0, 2.0], [2.0, 1.0]]))
    Traceback (most recent call last):
    fgopt.errors.NotPositiveDefiniteError: covariance is not positive definite ...
    """

    def __init__(self, message: str = "", variable: int | None = None):
        super().__init__(message)
        self.variable = variable


class NonFiniteError(FgoptError, ValueError):
    """A NaN or inf appeared in a value, residual or Jacobian.

    >>> fgopt.Variables().add(key('x', 0), np.array([np.nan, 1.0]))
    Traceback (most recent call last):
    fgopt.errors.NonFiniteError: value of x0 has a NaN or inf: ...
    """


class EmptyProblemError(FgoptError, ValueError):
    """The graph has no factors, or no variables to optimize.

    >>> fgopt.optimize(fgopt.FactorGraph(), fgopt.Variables())
    Traceback (most recent call last):
    fgopt.errors.EmptyProblemError: the factor graph is empty: add factors before optimizing
    """


class BackendUnavailableError(FgoptError, ImportError):
    """A linear-solver backend was selected but its library is missing.

    >>> from fgopt.errors import missing_extra
    >>> raise missing_extra("sksparse", "linear_solver='cholmod'")
    Traceback (most recent call last):
    fgopt.errors.BackendUnavailableError: linear_solver='cholmod' needs CHOLMOD ...
    """


class ManifoldError(FgoptError, TypeError):
    """A value's type is not a known manifold (register it, or give it dim/local/retract).

    >>> fgopt.SE2().compose(fgopt.SE3())
    Traceback (most recent call last):
    fgopt.errors.ManifoldError: SE2.compose: expected a SE2, got SE3
    """


class ManifoldDeclarationError(FgoptError, ValueError):
    """An ``@fgopt.manifold`` declaration is wrong (sizes, non-finite retract, ``local`` not the
    inverse of ``retract`` to first order); the message names the method and the failing check.

    >>> from fgopt.symbolic import V2
    >>> @fgopt.manifold
    ... class Stretched:
    ...     storage_dim = 2
    ...     dim = 2
    ...     def retract(x, d):
    ...         return V2(x[0] + d[0], x[1] + d[1])
    ...     def local(x, y):
    ...         return V2(y[0] - x[0], 2 * (y[1] - x[1]))
    ...
    Traceback (most recent call last):
    fgopt.errors.ManifoldDeclarationError: Stretched: local(x, retract(x, d)) is not d to first order...
    """


class FileFormatError(FgoptError, ValueError):
    """A data file is malformed; the message names the file and line.

    >>> import pathlib, tempfile
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "bad.g2o"
    >>> _ = path.write_text("VERTEX_SE2 0 1.0 2.0")
    >>> fgopt.io.read(path)
    Traceback (most recent call last):
    fgopt.errors.FileFormatError: .../bad.g2o:1: VERTEX_SE2 needs 4 numbers after the tag, found 3
    """

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
    that causes it is rejected exactly like a step that produces NaN.

    >>> from fgopt.cameras import Cal3_S2, PinholeCamera
    >>> camera = PinholeCamera(fgopt.SE3(), Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0))
    >>> camera.project(np.array([0.0, 0.0, -1.0]))
    Traceback (most recent call last):
    fgopt.errors.CheiralityError: PinholeCamera.project: point 0 [ 0.  0. -1.] is behind the camera ...
    """


class CalibrationError(FgoptError, ValueError):
    """A camera calibration is invalid (e.g. a non-positive focal length), or an iterative
    ``calibrate`` did not converge.

    >>> fgopt.cameras.Cal3_S2(0.0, 500.0, 0.0, 320.0, 240.0)
    Traceback (most recent call last):
    fgopt.errors.CalibrationError: Cal3_S2: focal length fx must be positive, got 0...
    """


class TriangulationError(FgoptError, ValueError):
    """A landmark cannot be triangulated: fewer than two views, or a rank-deficient system
    (the views' rays are parallel).

    >>> from fgopt.cameras import Cal3_S2, PinholeCamera, triangulate
    >>> camera = PinholeCamera(fgopt.SE3(), Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0))
    >>> triangulate([camera], np.array([[320.0, 240.0]]))
    Traceback (most recent call last):
    fgopt.errors.TriangulationError: triangulate: needs at least two views, got 1
    """


#: Optional extras: import name -> (extra, what it adds). ``pip install 'fgopt[<extra>]'``.
EXTRAS = {"sksparse": ("cholmod", "CHOLMOD (scikit-sparse; needs SuiteSparse)")}


def have_extra(module: str) -> bool:
    """Whether the optional dependency ``module`` (see :data:`EXTRAS`) is importable.

    >>> from fgopt.errors import have_extra
    >>> have_extra("numpy"), have_extra("no_such_module")
    (True, False)
    """
    import importlib.util

    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def missing_extra(module: str, feature: str) -> BackendUnavailableError:
    """The error for ``feature`` needing the absent optional dependency ``module``: it names the
    extra and the pip command that adds it.

    >>> from fgopt.errors import missing_extra
    >>> print(missing_extra("sksparse", "CholmodSolver"))  # doctest: +ELLIPSIS
    CholmodSolver needs CHOLMOD (scikit-sparse; needs SuiteSparse), which is not installed: pip install 'fgopt[cholmod]' ...
    """
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
