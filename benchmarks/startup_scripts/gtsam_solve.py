"""``fgopt solve FILE --out OUT`` done with GTSAM: read (g2o 2D/3D or BAL), LM with GTSAM's default
stopping rules (relative and absolute error decrease 1e-5, at most 100 iterations), write.

Pose graphs get GTSAM's example gauge prior on the first pose (as fgopt's CLI); BA none (LM
damping handles the gauge, as fgopt's CLI and Ceres' BAL example)."""

import sys

import numpy as np

import gtsam


def main(path: str, out: str) -> None:
    if path.endswith(".g2o"):
        is3d = any(line.startswith("VERTEX_SE3") for line in open(path))
        graph, initial = gtsam.readG2o(path, is3d)
        first = min(initial.keys())
        if is3d:
            model = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6] * 3 + [1e-4] * 3))
            graph.add(gtsam.PriorFactorPose3(first, initial.atPose3(first), model))
        else:
            model = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))
            graph.add(gtsam.PriorFactorPose2(first, initial.atPose2(first), model))
        opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams())
        result = opt.optimize()
        gtsam.writeG2o(graph, result, out)
    else:
        from gtsam.symbol_shorthand import C, P

        scene = gtsam.SfmData.FromBalFile(path)
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
        opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams())
        result = opt.optimize()
        solved = gtsam.SfmData()  # the python wrapper has no writeBALfromValues
        for i in range(scene.numberCameras()):
            solved.addCamera(result.atPinholeCameraCal3Bundler(C(i)))
        for j in range(scene.numberTracks()):
            track = scene.track(j)
            track.p = result.atPoint3(P(j))
            solved.addTrack(track)
        gtsam.writeBAL(out, solved)
    print(f"cost {graph.error(initial):.6e} -> {graph.error(result):.6e}, {opt.iterations()} "
          f"iterations, {lm_status(opt)}")


def lm_status(opt) -> str:
    """Why GTSAM's LM stopped: its iteration limit, its lambda bound (it gave up), or else its
    own convergence test (relative / absolute error decrease)."""
    params = gtsam.LevenbergMarquardtParams()
    if opt.iterations() >= params.getMaxIterations():
        return "max iterations"
    if opt.lambda_() > params.getlambdaUpperBound():
        return "gave up (lambda above its upper bound)"
    return "converged"


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
