"""GTSAM (PyPI wheel) runner: ``readG2o`` + prior on the first pose, ``readBal`` + GeneralSFMFactor,
``LevenbergMarquardtOptimizer`` with ``LevenbergMarquardtParams`` (multifrontal Cholesky, COLAMD:
GTSAM's defaults)."""

from __future__ import annotations

import numpy as np

from . import SolveOutput



def lm_params(mode: str):
    """GTSAM's default LM parameters; ``"5it"``: exactly 5 iterations (all tolerances 0)."""
    import gtsam

    params = gtsam.LevenbergMarquardtParams()
    if mode == "5it":
        params.setMaxIterations(5)
        params.setRelativeErrorTol(0.0)
        params.setAbsoluteErrorTol(0.0)
        params.setErrorTol(0.0)
    return params

def lm_status(opt, params) -> str:
    """Why GTSAM's LM stopped: its iteration limit, its lambda bound (it gave up), or else its
    own convergence test fired (relative / absolute error decrease below tolerance)."""
    if opt.iterations() >= params.getMaxIterations():
        return "max iterations"
    if opt.lambda_() > params.getlambdaUpperBound():
        return "gave up (lambda above its upper bound)"
    return "converged"


class GtsamRunner:
    name = "gtsam"
    pinning = "wheel has no TBB (single thread); BLAS env vars = 1"
    note = ""

    def version(self) -> str:
        import importlib.metadata as md

        return md.version("gtsam")

    def supports(self, problem) -> str | None:
        return None

    # ------------------------------------------------------------------------------------------
    def load(self, spec):
        import gtsam

        if spec.kind in ("pose2d", "pose3d"):
            is3d = spec.kind == "pose3d"
            graph, initial = gtsam.readG2o(str(spec.path), is3d)
            keys = sorted(initial.keys())
            first = keys[0]
            # GTSAM's examples (Pose2SLAMExample_g2o.py / Pose3SLAMExample_g2o.py): tiny-variance
            # prior on the first pose (here at its initial value rather than the identity).
            if is3d:
                model = gtsam.noiseModel.Diagonal.Variances(
                    np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4]))
                graph.add(gtsam.PriorFactorPose3(first, initial.atPose3(first), model))
            else:
                model = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))
                graph.add(gtsam.PriorFactorPose2(first, initial.atPose2(first), model))
            return {"kind": spec.kind, "graph": graph, "initial": initial, "keys": keys}
        if spec.kind == "bal":
            return self._load_bal(spec)
        if spec.kind == "robot_localization":
            return self._load_robot()
        raise ValueError(spec.kind)

    def _load_bal(self, spec):
        import gtsam
        from gtsam.symbol_shorthand import C, P

        # As GTSAM's SFMExample_bal.py, but without its two gauge priors (protocol: no gauge
        # fixing in BA, LM damping handles it, as Ceres' BAL example).
        scene = gtsam.readBal(str(spec.path))
        graph = gtsam.NonlinearFactorGraph()
        noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
        initial = gtsam.Values()
        for j in range(scene.numberTracks()):
            track = scene.track(j)
            for m in range(track.numberMeasurements()):
                i, uv = track.measurement(m)
                graph.add(gtsam.GeneralSFMFactorCal3Bundler(uv, noise, C(i), P(j)))
            initial.insert(P(j), track.point3())
        for i in range(scene.numberCameras()):
            initial.insert(C(i), scene.camera(i))
        return {"kind": "bal", "graph": graph, "initial": initial,
                "ncam": scene.numberCameras(), "npt": scene.numberTracks()}

    def _load_robot(self):
        import gtsam
        from gtsam.symbol_shorthand import L, X

        from ..problems import robot_localization

        p = robot_localization()
        graph = gtsam.NonlinearFactorGraph()
        initial = gtsam.Values()
        br_noise = gtsam.noiseModel.Diagonal.Sigmas(p.br_sigmas)
        odo_noise = gtsam.noiseModel.Diagonal.Sigmas(p.odom_sigmas)
        # GTSAM has no factor to a known point: landmarks are variables pinned by tight priors.
        lm_noise = gtsam.noiseModel.Isotropic.Sigma(2, 1e-4)
        for j, lm in enumerate(p.landmarks):
            initial.insert(L(j), lm.copy())
            graph.add(gtsam.PriorFactorPoint2(L(j), lm.copy(), lm_noise))
        for i, x in enumerate(p.poses):
            initial.insert(X(i), gtsam.Pose2(*x))
        for k in range(len(p.br_meas)):
            b, r = p.br_meas[k]
            graph.add(gtsam.BearingRangeFactor2D(X(int(p.br_pose[k])), L(int(p.br_lm[k])),
                                                 gtsam.Rot2(b), float(r), br_noise))
        for k, z in enumerate(p.odom_meas):
            graph.add(gtsam.BetweenFactorPose2(X(k), X(k + 1), gtsam.Pose2(*z), odo_noise))
        return {"kind": "robot_localization", "graph": graph, "initial": initial,
                "n": len(p.poses)}

    # ------------------------------------------------------------------------------------------
    def reset(self, state):
        pass  # the optimizer never changes `initial`

    def solve(self, state, mode):
        import gtsam

        opt = gtsam.LevenbergMarquardtOptimizer(state["graph"], state["initial"],
                                                lm_params(mode))
        initial_error = opt.error()  # computed by the constructor already
        values = opt.optimize()
        return SolveOutput(values, opt.iterations(), initial_error, opt.error(),
                           lm_status(opt, lm_params(mode)))

    def estimate(self, state, out):
        import gtsam
        from scipy.spatial.transform import Rotation

        values = out.raw
        kind = state["kind"]
        if kind == "pose2d":
            return {"poses": gtsam.utilities.extractPose2(values)}
        if kind == "pose3d":
            m = gtsam.utilities.extractPose3(values)
            q = Rotation.from_matrix(m[:, :9].reshape(-1, 3, 3)).as_quat()
            return {"poses": np.concatenate([m[:, 9:12], q], axis=1)}
        if kind == "bal":
            from gtsam.symbol_shorthand import C

            cams = [values.atPinholeCameraCal3Bundler(C(i)) for i in range(state["ncam"])]
            return {"cameras": cameras_to_bal(cams),
                    "points": gtsam.utilities.extractPoint3(values).reshape(-1, 3)}
        if kind == "robot_localization":
            return {"poses": gtsam.utilities.extractPose2(values)}
        raise ValueError(kind)

    def lib_cost(self, state, values) -> float:
        return state["graph"].error(values)


def cameras_to_bal(cams) -> np.ndarray:
    """GTSAM ``PinholeCameraCal3Bundler`` (pose wTc, z forward) -> BAL rows (inverse of the
    conversion ``gtsam.readBal`` applies: ``wRc = R^T Rx(pi)``, centre ``-R^T t``)."""
    from scipy.spatial.transform import Rotation

    Rx = np.diag([1.0, -1.0, -1.0])
    out = np.zeros((len(cams), 9))
    for i, cam in enumerate(cams):
        pose = cam.pose()
        wRc = pose.rotation().matrix()
        centre = pose.translation()
        R = Rx @ wRc.T
        out[i, 0:3] = Rotation.from_matrix(R).as_rotvec()
        out[i, 3:6] = -R @ centre
        k = cam.calibration()
        out[i, 6:9] = [k.fx(), k.k1(), k.k2()]
    return out


RUNNER = GtsamRunner()
