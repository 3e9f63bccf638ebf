"""Symbolic geometry, tangent-space Jacobians and generated numba kernels (SymForce-style).

Write a residual once over symbolic types, get a batched numba kernel for its residual and
tangent-space Jacobians::

    from fgopt.symbolic import Pose2, V2, atan2

    @fgopt.factor
    def range_bearing(pose: Pose2, landmark: V2, measured: V2) -> V2:
        d = pose.inverse() * landmark
        return V2(d.norm(), atan2(d[1], d[0])) - measured

Module map (one job each): ``matrix`` (Matrix, V1..V9, Scalar), ``lie`` (group base),
``rot`` (Rot2, Rot3), ``pose`` (Pose2, Pose3), ``navstate`` (NavState), ``cameras`` (SnavelyCamera, PinholeCamera),
``functions`` (epsilon-safe math), ``_sym`` (SymPy side: epsilon, sign_no_zero),
``ops`` (storage/tangent ops), ``jacobians`` (tangent-space Jacobians), ``singularity``
(removable-singularity checker), ``linearize`` (residual + Jacobian programs), ``cse``,
``printer``, ``codegen`` (kernel modules), ``cache`` (on-disk cache), ``derive`` (a factor's
kernel source), ``runtime`` (helpers of generated code), ``generated`` (:func:`generate`:
functions with tangent Jacobians as numba functions; derived in ``_generate_source``), ``declare``
(``@fgopt.manifold``: user-declared manifolds, ``Product``, ``check_manifold``), ``geometry``
(manifolds declared that way that ship with fgopt: ``Unit3``, ``OrientedPlane3``, ``SE23``;
loaded on first access). ``@fgopt.factor`` itself, which makes factor types from these, is
:mod:`fgopt.factors.decorator` (the factors layer).

Importing this package does not import SymPy; ``epsilon`` and ``pi`` (SymPy objects) load it on
first access.
"""

from __future__ import annotations

from typing import Any

from . import cache as cache
from .cameras import PinholeCamera as PinholeCamera
from .cameras import SnavelyCamera as SnavelyCamera
from .cameras import angle_axis_rotate as angle_axis_rotate
from .functions import Abs as Abs
from .functions import Max as Max
from .functions import Min as Min
from .functions import acos as acos
from .functions import asin as asin
from .functions import atan as atan
from .functions import atan2 as atan2
from .functions import clamp as clamp
from .functions import cos as cos
from .functions import cosh as cosh
from .functions import exp as exp
from .functions import floor as floor
from .functions import log as log
from .functions import safe_div as safe_div
from .functions import sign as sign
from .functions import sign_no_zero as sign_no_zero
from .functions import sin as sin
from .functions import sinh as sinh
from .functions import snz as snz
from .functions import sqrt as sqrt
from .functions import symbols as symbols
from .functions import tan as tan
from .functions import tanh as tanh
from .functions import where as where
from .lie import LieGroupBase as LieGroupBase
from .matrix import M22 as M22
from .matrix import M33 as M33
from .matrix import M44 as M44
from .matrix import V1 as V1
from .matrix import V2 as V2
from .matrix import V3 as V3
from .matrix import V4 as V4
from .matrix import V5 as V5
from .matrix import V6 as V6
from .matrix import V7 as V7
from .matrix import V8 as V8
from .matrix import V9 as V9
from .matrix import Matrix as Matrix
from .matrix import Scalar as Scalar
from .matrix import vector_type as vector_type
from .navstate import NavState as NavState
from .pose import Pose2 as Pose2
from .pose import Pose3 as Pose3
from .rot import Rot2 as Rot2
from .rot import Rot3 as Rot3

_LAZY = {
    "epsilon": ("._sym", "epsilon"),
    "EPSILON_VALUE": ("._sym", "EPSILON_VALUE"),
    "pi": ("._sym", None),
    "tangent_jacobians": (".jacobians", "tangent_jacobians"),
    "jacobians_of": (".jacobians", "jacobians_of"),
    "linearization_program": (".linearize", "linearization_program"),
    "check_removable_singularity": (".singularity", "check_removable_singularity"),
    "python_function": (".codegen", "python_function"),
    "total_ops": (".cse", "total_ops"),
    "generate": (".generated", "generate"),
    "GeneratedFunction": (".generated", "GeneratedFunction"),
    "manifold": (".declare", "manifold"),
    "Product": (".declare", "Product"),
    "check_manifold": (".declare", "check_manifold"),
    "DeclaredManifold": (".declare", "DeclaredManifold"),
    "Unit3": (".geometry", "Unit3"),
    "OrientedPlane3": (".geometry", "OrientedPlane3"),
    "SE23": (".geometry", "SE23"),
}


#: ``@factor`` lives in the factors layer (it makes Factor types); these names stay reachable from
#: ``fgopt.symbolic`` because user code and notebooks import them from here.
_FACTOR_NAMES = ("factor", "SymbolicFactor", "SymbolicFactorType")


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        mod, attr = _LAZY[name]
        m = importlib.import_module(mod, __name__)
        return m.sp.pi if name == "pi" else getattr(m, attr)
    if name in _FACTOR_NAMES:
        # layer-exception: a compatibility alias resolved on first use, once the factors layer
        # is importable; nothing in fgopt.symbolic itself uses these names.
        from ..factors import decorator

        return getattr(decorator, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

#: The public names (each has an entry in the API reference: tests/test_docs_reference.py).
__all__ = ["PinholeCamera", "SnavelyCamera", "angle_axis_rotate", "Abs", "Max", "Min", "acos",
           "asin", "atan", "atan2", "clamp", "cos", "cosh", "exp", "floor", "log", "safe_div",
           "sign", "sign_no_zero", "sin", "sinh", "snz", "sqrt", "symbols", "tan", "tanh", "where",
           "LieGroupBase", "M22", "M33", "M44", "V1", "V2", "V3", "V4", "V5", "V6", "V7", "V8",
           "V9", "Matrix", "Scalar", "vector_type", "NavState", "Pose2", "Pose3", "Rot2", "Rot3",
           "epsilon", "pi", "tangent_jacobians", "jacobians_of", "linearization_program",
           "check_removable_singularity", "python_function", "total_ops", "generate",
           "GeneratedFunction", "manifold", "Product", "check_manifold", "DeclaredManifold",
           "Unit3", "OrientedPlane3", "SE23"]
