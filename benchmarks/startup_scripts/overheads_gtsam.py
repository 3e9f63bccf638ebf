"""Per-process overheads of GTSAM, as ``overheads_fgopt.py`` (prints JSON)."""

import json
import sys
import time

t0 = time.perf_counter()
import gtsam  # noqa: E402

out = {"import gtsam": time.perf_counter() - t0}
path = sys.argv[1]
sys.path.insert(0, __file__.rsplit("/", 1)[0])


def read():
    if path.endswith(".g2o"):
        import numpy as np

        is3d = any(line.startswith("VERTEX_SE3") for line in open(path))
        graph, initial = gtsam.readG2o(path, is3d)
        first = min(initial.keys())
        if is3d:
            model = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6] * 3 + [1e-4] * 3))
            graph.add(gtsam.PriorFactorPose3(first, initial.atPose3(first), model))
        else:
            model = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))
            graph.add(gtsam.PriorFactorPose2(first, initial.atPose2(first), model))
        return graph, initial
    from gtsam.symbol_shorthand import C, P

    scene = gtsam.SfmData.FromBalFile(path)
    graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    for j in range(scene.numberTracks()):
        track = scene.track(j)
        for m in range(track.numberMeasurements()):
            i, uv = track.measurement(m)
            graph.add(gtsam.GeneralSFMFactorCal3Bundler(uv, noise, C(i), P(j)))
        initial.insert(P(j), track.point3())
    for i in range(scene.numberCameras()):
        initial.insert(C(i), scene.camera(i))
    return graph, initial


t = time.perf_counter()
graph, initial = read()
out["first read"] = time.perf_counter() - t
t = time.perf_counter()
read()
out["second read"] = time.perf_counter() - t
params = gtsam.LevenbergMarquardtParams()
if not path.endswith(".g2o"):
    params.setMaxIterations(5)  # GTSAM needs 100 iterations on Ladybug: keep the probe short
t = time.perf_counter()
gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
out["first optimize"] = time.perf_counter() - t
t = time.perf_counter()
gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
out["second optimize"] = time.perf_counter() - t
print(json.dumps(out))
