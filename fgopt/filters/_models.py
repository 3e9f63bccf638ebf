"""The symbolic functions a :class:`~fgopt.filters.ekf.ManifoldEKF` generates from the user's.

All three take the state first, so the state's storage is the prefix of every generated
function's flat input and the filter copies one vector, not one per argument:

* ``process_model(*state, *inputs, dt) -> tuple(state)``: the user's process function with its
  arguments in this order; differentiated by state and inputs, ``[F | G]``.
* ``innovation(*state, *params, z) -> local(h(x, params), z)``: the measurement residual in the
  measurement's tangent space (``z - h`` for vectors, ``Log(h^-1 z)`` for groups);
  differentiated by the state, ``J = d y / d x = -H``.
* ``retract(*state, *deltas) -> tuple(state (+) delta)``: the correction through each
  component's retraction; differentiated by the deltas, the Jacobian is the reset
  ``d local(x+, x (+) (delta + e)) / d e`` that moves the covariance to the tangent space at
  the corrected state.

The wrappers close only over user functions and flat tuples of indices, which the kernel
cache's function fingerprint hashes by value (:func:`fgopt.symbolic.cache.function_fingerprint`).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence
from typing import Any

from ..symbolic import Matrix, Scalar
from ..symbolic.ops import has_own_tangent


def is_declared_value(v: Any) -> bool:
    """A value of a manifold declared with ``@fgopt.manifold``."""
    from ..symbolic.declare.twin import DeclaredManifold

    return isinstance(v, DeclaredManifold)


def _with_signature(fn: Callable, name: str, params: Sequence[tuple[str, type]]) -> Callable:
    fn.__name__ = fn.__qualname__ = name
    fn.__signature__ = inspect.Signature(
        [inspect.Parameter(n, inspect.Parameter.POSITIONAL_OR_KEYWORD, annotation=tp)
         for n, tp in params])
    fn.__annotations__ = dict(params)
    return fn


def tangent_type(tp: type) -> type:
    """The symbolic vector type of ``tp``'s tangent space (``Scalar`` for scalars)."""
    if tp is Scalar:
        return Scalar
    if issubclass(tp, Matrix):
        return Matrix.shaped(tp.storage_dim(), 1)
    return Matrix.shaped(tp.dim(), 1)


def retract_value(x: Any, d: Any) -> Any:
    """``x (+) d`` for a symbolic value (group: ``x * Exp(d)``; vector / scalar: ``x + d``)."""
    if has_own_tangent(x):
        return x.retract(d)
    if isinstance(x, Matrix):
        return type(x).from_storage([a + b for a, b in zip(x.to_storage(), d.to_storage())])
    return x + d


def local_value(a: Any, b: Any) -> Any:
    """``b (-) a`` in ``a``'s tangent space (group: ``Log(a^-1 b)``; vector: ``b - a``)."""
    if has_own_tangent(a):
        return a.local(b)
    if isinstance(a, Matrix):
        return Matrix.shaped(len(a), 1)([v - u for u, v in zip(a.to_storage(), b.to_storage())])
    return b - a


def process_model(process: Callable, order: tuple, params: Sequence[tuple[str, type]],
                  nstate: int) -> Callable:
    """``process`` with arguments in canonical order; ``order[i]`` is the canonical index of
    the user's argument ``i``. Always returns a tuple of the ``nstate`` next values."""
    single = nstate == 1

    def process_model(*args):
        out = process(*[args[j] for j in order])
        if single and not isinstance(out, (tuple, list)):
            out = (out,)
        # declared manifolds come back projected by their own normalize (quaternions of the
        # built-in groups are renormalized numerically after each step instead)
        return tuple(o.normalize() if is_declared_value(o) else o for o in out)

    return _with_signature(process_model, f"{process.__name__}_process", params)


def innovation(measure: Callable, select: tuple, params: Sequence[tuple[str, type]],
               name: str) -> Callable:
    """``local(measure(args[select]), z)`` with ``z`` the last argument."""

    def innovation(*args):
        return local_value(measure(*[args[j] for j in select]), args[-1])

    return _with_signature(innovation, f"{name}_innovation", params)


def prediction(measure: Callable, select: tuple, params: Sequence[tuple[str, type]],
               name: str) -> Callable:
    """``measure(args[select])``: the predicted measurement, state first."""

    def prediction(*args):
        return measure(*[args[j] for j in select])

    return _with_signature(prediction, f"{name}_prediction", params)


def state_retract(params: Sequence[tuple[str, type]], nstate: int, name: str) -> Callable:
    """``tuple(x_i (+) d_i)`` for state values then deltas."""

    def retract(*args):
        return tuple(retract_value(args[i], args[nstate + i]) for i in range(nstate))

    return _with_signature(retract, f"{name}_retract", params)
