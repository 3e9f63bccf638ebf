"""Bundle-adjustment problems in GTSAM's camera form: SE(3) poses + ``Cal3Bundler`` + points.

Bundler and BAL store a camera as the world-to-camera rotation ``R`` and translation ``t`` of an
OpenGL-style camera (looking down -z, y up) and a pixel with the image centre as origin and y up.
GTSAM's form (``SfmData``'s ``openGL2gtsam``) is a pose ``world_T_camera`` looking down +z with y
down: ``world_R_camera = R^T diag(1, -1, -1)``, position ``-R^T t``, the calibration
``Cal3Bundler(f, k1, k2, 0, 0)`` and the pixel ``(u, -v)``. The reprojection residuals then
equal the Snavely residuals up to the sign of their second component, so the cost is the same.

Three forms (``form=``): ``"camera"``, one :class:`~fgopt.cameras.PinholeCamera` variable
``c<i>`` (pose + Cal3Bundler, GTSAM's ``SfmCamera``) per camera; ``"pose+calibration"``, SE(3)
``x<i>`` and Cal3Bundler ``k<i>`` variables; ``"pose"``, SE(3) ``x<i>`` with the calibrations
fixed. Points are ``p<j>`` (numbered as in the file). The graph has one batch of projection
factors with unit noise (pixels) and ``cheirality="allow"``: BAL / Bundler costs count
observations behind a camera, so every form reaches the Snavely form's cost (Ladybug-49's
initial estimate has 31 of them).
"""

from __future__ import annotations

import numpy as np

from ..cameras import Cal3Bundler, PinholeCamera
from ..cameras.factors import camera_projection_kernel, projection_kernel
from ..graph import FactorGraph
from ..key import key
from ..manifolds import SE3, SO3
from ..manifolds.base import vector_kind
from ..variables import Variables

FORMS = ("camera", "pose+calibration", "pose")
_FLIP = np.diag([1.0, -1.0, -1.0])


def gtsam_form_graph(R: np.ndarray, t: np.ndarray, intrinsics: np.ndarray, cam_idx: np.ndarray,
                     pt_idx: np.ndarray, uv: np.ndarray, points: np.ndarray, form: str,
                     origin: tuple | None) -> tuple[FactorGraph, Variables]:
    """Graph + values of a Snavely-convention problem in GTSAM's form (module docstring).

    ``R (nc, 3, 3)`` / ``t (nc, 3)`` world-to-camera (OpenGL), ``intrinsics (nc, 3)`` ``f, k1,
    k2``, observations ``cam_idx``, ``pt_idx``, ``uv (n, 2)`` (y up), ``points (np, 3)``.
    ``form``: ``"camera"`` (a PinholeCamera[Cal3Bundler] variable ``c<i>`` per camera: GTSAM's
    ``SfmCamera`` / ``GeneralSFMFactor``), ``"pose+calibration"`` (SE3 ``x<i>`` and Cal3Bundler
    ``k<i>`` variables: ``GeneralSFMFactor2``) or ``"pose"`` (SE3 ``x<i>``, calibrations fixed).
    """
    nc = R.shape[0]
    pose_rows = np.empty((nc, 7))
    for i in range(nc):
        wRc = R[i].T @ _FLIP
        pose_rows[i] = SE3(SO3.from_matrix(wRc), -R[i].T @ t[i]).to_storage()
    cal_rows = np.column_stack([intrinsics, np.zeros((nc, 2))])
    cb, xb, kb, pb = (int(key(c, 0)) for c in "cxkp")
    values = Variables()
    values.add_rows(np.arange(pb, pb + points.shape[0], dtype=np.int64), vector_kind(3), points)
    meas = np.column_stack([uv[:, 0], -uv[:, 1]])
    ci, pj = cam_idx.astype(np.int64), pt_idx.astype(np.int64)
    graph = FactorGraph()
    if form == "camera":
        values.add_rows(np.arange(cb, cb + nc, dtype=np.int64),
                        PinholeCamera.batch_kind_of(Cal3Bundler),
                        np.column_stack([pose_rows, cal_rows]))
        graph.add_batch(camera_projection_kernel(Cal3Bundler, "allow"),
                        np.column_stack([cb + ci, pb + pj]), meas, None, origin=origin)
        return graph, values
    values.add_rows(np.arange(xb, xb + nc, dtype=np.int64), SE3.batch_kind(), pose_rows)
    if form == "pose+calibration":
        values.add_rows(np.arange(kb, kb + nc, dtype=np.int64), Cal3Bundler.batch_kind(), cal_rows)
        graph.add_batch(projection_kernel(Cal3Bundler, True, "allow"),
                        np.column_stack([xb + ci, pb + pj, kb + ci]), meas, None, origin=origin)
    else:
        graph.add_batch(projection_kernel(Cal3Bundler, False, "allow"),
                        np.column_stack([xb + ci, pb + pj]),
                        np.column_stack([meas, cal_rows[ci]]), None, origin=origin)
    return graph, values


def rotations_from_angle_axis(r: np.ndarray) -> np.ndarray:
    """``(n, 3, 3)`` rotation matrices of angle-axis vectors ``r (n, 3)``."""
    return np.array([SO3.exp(v).matrix() for v in r]).reshape(-1, 3, 3)
