"""Numba kernels of the Lie groups SO(2), SE(2), SO(3), SE(3) and Sim(3): one implementation.

One module per group (``so2``, ``se2``, ``so3`` with the unit-quaternion helpers, ``se3``,
``sim3``), shared helpers in ``_common`` (group ids and sizes, small block algebra, ``phi``),
and ``dispatch`` (by group id, and the batched loops); this package re-exports them all.

Three layers, all ``@njit(cache=True)``:

1. per-element helpers, one per group and operation (``so3_exp(w, out)``, ``se3_jrinv(xi, out)``,
   ``quat_mul(a, b, out)``...). They write into ``out`` (which must not alias an input) and do
   not allocate, except the Sim(3) Jacobians;
2. per-element dispatchers over a group id (``lie_compose(gid, a, b, out)``, ``lie_log``,
   ``lie_jrinv``...), which the value classes call one element at a time and the factor
   kernels call inside their loops;
3. batched loops over ``(n, storage_dim)`` arrays (``batch_retract(gid, x, delta)``...), and
   ``<group>_retract_batch`` / ``<group>_local_batch`` entries per group for ``BatchKind``.

Layers 2 and 3 are ``inline="always"``: callers reach them through an entry with a constant
group id (:func:`fgopt._jit.specialize`), which compiles only that group's branch.

Layouts (float64, 1-D), tangent order rotation first::

    SO2   storage [cos, sin]                    tangent [theta]
    SE2   storage [cos, sin, x, y]              tangent [theta, vx, vy]
    SO3   storage [qx, qy, qz, qw]              tangent [wx, wy, wz]
    SE3   storage [qx, qy, qz, qw, tx, ty, tz]  tangent [w(3), v(3)]
    Sim3  storage [q(4), t(3), s]               tangent [w(3), v(3), lambda],  s = exp(lambda)

Conventions: ``retract(x, d) = x * Exp(d)``, ``local(a, b) = Log(a^-1 * b)`` (true group
exponential, right perturbation, as GTSAM's Pose2/Pose3 defaults). The adjoint satisfies
``x * Exp(v) = Exp(Adj(x) v) * x``; ``ad(xi)`` is its derivative, ``[hat(a), hat(b)] =
hat(ad(a) b)``. The right Jacobian satisfies ``Exp(xi + d) ~= Exp(xi) * Exp(Jr(xi) d)``, so
``Jr(xi) = phi(-ad(xi))`` with ``phi(A) = sum_k A^k / (k+1)!``, and ``Jl(xi) = Jr(-xi)``.

Exp(SE3) = (Exp(w), V(w) v) with V = Jl_SO3(w) = I + a W + b W^2, a = (1 - cos t)/t^2,
b = (t - sin t)/t^3 (W = hat(w), t = |w|); V^-1 = I - W/2 + c W^2, c = 1/t^2 - cot(t/2)/(2t).
The SE(3) Jacobian is block triangular, ``Jr = [[Jr_SO3, 0], [Q(-w, -v), Jr_SO3]]`` with
Barfoot's Q ("State Estimation for Robotics", eq. 7.86). Sim(3) (Eade, "Lie groups for computer
vision"): t = W(w, lambda) v with W = int_0^1 e^(s lambda) R(s w) ds = a0 I + a1 W + a2 W^2,
evaluated through the complex number (e^z - 1)/z, z = lambda + i t; its Jacobians are computed
to rounding error from ``phi(-ad)`` by scaling and squaring (no closed form here).

Removable singularities at angle 0 switch to Taylor series below thresholds where the
truncation error is below 1e-17; at angle pi no formula divides by sin(t) or 1 + cos(t).
"""

from ._common import GROUP_NAMES as GROUP_NAMES
from ._common import MAX_DIM as MAX_DIM
from ._common import MAX_STORAGE_DIM as MAX_STORAGE_DIM
from ._common import SE2_ID as SE2_ID
from ._common import SE3_ID as SE3_ID
from ._common import SIM3_ID as SIM3_ID
from ._common import SO2_ID as SO2_ID
from ._common import SO3_ID as SO3_ID
from ._common import STORAGE_DIMS as STORAGE_DIMS
from ._common import TANGENT_DIMS as TANGENT_DIMS
from ._common import copy_block3 as copy_block3
from ._common import fill_block as fill_block
from ._common import invert as invert
from ._common import jr_from_ad as jr_from_ad
from ._common import matmul as matmul
from ._common import matmul_block3 as matmul_block3
from ._common import phi_matrix as phi_matrix
from ._common import skew_poly3 as skew_poly3
from ._common import skew_poly_apply as skew_poly_apply
from ._common import storage_dim as storage_dim
from ._common import tangent_dim as tangent_dim
from .so2 import so2_ad as so2_ad
from .so2 import so2_compose as so2_compose
from .so2 import so2_exp as so2_exp
from .so2 import so2_eye as so2_eye
from .so2 import so2_inverse as so2_inverse
from .so2 import so2_log as so2_log
from .se2 import se2_ad as se2_ad
from .se2 import se2_adjoint as se2_adjoint
from .se2 import se2_compose as se2_compose
from .se2 import se2_exp as se2_exp
from .se2 import se2_inverse as se2_inverse
from .se2 import se2_jr as se2_jr
from .se2 import se2_jrinv as se2_jrinv
from .se2 import se2_log as se2_log
from .so3 import quat_from_matrix as quat_from_matrix
from .so3 import quat_mul as quat_mul
from .so3 import quat_normalize as quat_normalize
from .so3 import quat_rotate as quat_rotate
from .so3 import quat_to_matrix as quat_to_matrix
from .so3 import rotation_block as rotation_block
from .so3 import so3_ad as so3_ad
from .so3 import so3_adjoint as so3_adjoint
from .so3 import so3_coeffs as so3_coeffs
from .so3 import so3_compose as so3_compose
from .so3 import so3_exp as so3_exp
from .so3 import so3_inverse as so3_inverse
from .so3 import so3_jr as so3_jr
from .so3 import so3_jrinv as so3_jrinv
from .so3 import so3_log as so3_log
from .se3 import se3_ad as se3_ad
from .se3 import se3_adjoint as se3_adjoint
from .se3 import se3_compose as se3_compose
from .se3 import se3_exp as se3_exp
from .se3 import se3_inverse as se3_inverse
from .se3 import se3_jr as se3_jr
from .se3 import se3_jrinv as se3_jrinv
from .se3 import se3_log as se3_log
from .se3 import se3_q as se3_q
from .sim3 import sim3_ad as sim3_ad
from .sim3 import sim3_adjoint as sim3_adjoint
from .sim3 import sim3_compose as sim3_compose
from .sim3 import sim3_exp as sim3_exp
from .sim3 import sim3_inverse as sim3_inverse
from .sim3 import sim3_jr as sim3_jr
from .sim3 import sim3_jrinv as sim3_jrinv
from .sim3 import sim3_log as sim3_log
from .sim3 import sim3_w_coeffs as sim3_w_coeffs
from .dispatch import LOCAL_BATCH as LOCAL_BATCH
from .dispatch import RETRACT_BATCH as RETRACT_BATCH
from .dispatch import batch_local as batch_local
from .dispatch import retract_rows as retract_rows
from .dispatch import batch_retract as batch_retract
from .dispatch import retract_row as retract_row
from .dispatch import lie_ad as lie_ad
from .dispatch import lie_adjoint as lie_adjoint
from .dispatch import lie_compose as lie_compose
from .dispatch import lie_exp as lie_exp
from .dispatch import lie_inverse as lie_inverse
from .dispatch import lie_jr as lie_jr
from .dispatch import lie_jrinv as lie_jrinv
from .dispatch import lie_local as lie_local
from .dispatch import lie_log as lie_log
from .dispatch import lie_retract as lie_retract
from .dispatch import se2_local_batch as se2_local_batch
from .dispatch import se2_retract_batch as se2_retract_batch
from .dispatch import se3_local_batch as se3_local_batch
from .dispatch import se3_retract_batch as se3_retract_batch
from .dispatch import sim3_local_batch as sim3_local_batch
from .dispatch import sim3_retract_batch as sim3_retract_batch
from .dispatch import so2_local_batch as so2_local_batch
from .dispatch import so2_retract_batch as so2_retract_batch
from .dispatch import so3_local_batch as so3_local_batch
from .dispatch import so3_retract_batch as so3_retract_batch
