"""Vision benchmark: fgopt's cameras vs fgopt's BAL kernel, C++ Ceres and GTSAM, in one run.

    .venv/bin/python -m benchmarks.vision [--sections ladybug,stereo_vo,smart_sfm,sfm]
        [--rounds 3] [--json out.json]

Sections (every number a median over ``--rounds`` interleaved rounds, after a warm-up; CPU =
``time.process_time`` of this single-threaded process, wall = ``perf_counter``):

* ``ladybug`` -- Ladybug-49 (BAL) read three ways: the 9-vector Snavely camera (fgopt's BAL
  kernel), GTSAM's camera form as one ``PinholeCamera[Cal3Bundler]`` variable per camera
  (``read_bal(form="camera")``, GTSAM's ``SfmCamera``), and as separate SE3 + Cal3Bundler
  variables (``form="pose+calibration"``). Per form: CPU of one LM iteration at the initial
  estimate (:func:`benchmarks.ba.profile_iteration`, best of 15: linearize, assemble, Schur
  solve, retract, cost), CPU / wall of exactly 5 LM iterations (stopping tests off), and the
  converged cost. C++ Ceres (``benchmarks/ceres_cpp``, SPARSE_SCHUR, 9-vector form) when built.
  Target: the camera form's iteration within 1.3x of the Snavely kernel's.
* ``stereo_vo`` -- GTSAM's ``StereoVOExample_large`` (8189 stereo factors, 26 poses): fgopt
  (``read_stereo_vo``, LM defaults) vs GTSAM as its example runs it (``NonlinearEquality`` on x1,
  LM with METIS), and GTSAM with fgopt's tight prior instead; times, final costs, largest pose
  difference. Target: fgopt at most GTSAM's time.
* ``smart_sfm`` -- the SFMExample scene with one ``SmartProjectionFactor`` per landmark vs
  GTSAM's ``SmartProjectionPoseFactorCal3_S2`` graph (LM defaults). Target: at most GTSAM's time.
* ``smart_large`` -- a larger synthetic smart-factor problem (:func:`smart_ring`: 60 cameras,
  1500 tracks of 3-10 views, pixel noise), fgopt vs GTSAM, LM defaults.
* ``sfm`` -- SFMExample with projection factors, Dogleg (as GTSAM's script) in both.

Small problems are solved repeatedly inside one sample (``--inner``) so timer resolution and
Python start-up noise do not dominate. On a shared machine compare the ratios of one run only.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
           "MKL_NUM_THREADS", "NUMBA_NUM_THREADS",
           "VECLIB_MAXIMUM_THREADS"):
    os.environ[_v] = "1"
# Warm-process figures: small batches on the compiled kernels from the first timed call (a
# process reaches this after 0.5 s of NumPy-twin work; see fgopt/_jit.py).
os.environ.setdefault("FGOPT_NUMPY_BUDGET", "0")
# ... and the small-problem drivers (fgopt.solvers.small: the smart SFM scene) compiled by the
# warm-up solve, not in a background process while the timed solves run
os.environ.setdefault("FGOPT_SMALL_COMPILE", "1")

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

SECTIONS = ("ladybug", "stereo_vo", "smart_sfm", "smart_large", "sfm")


def _data(rel: str) -> Path:
    from fgopt.datasets import data_dir

    return data_dir() / rel


def _timed(fn, inner: int = 1) -> tuple[float, float, object]:
    """(wall, cpu) per call of ``fn`` over ``inner`` calls, and its last result."""
    w, c = time.perf_counter(), time.process_time()
    out = None
    for _ in range(inner):
        out = fn()
    return (time.perf_counter() - w) / inner, (time.process_time() - c) / inner, out


def _median_runs(fns: dict, rounds: int, inner: int = 1) -> dict:
    """Warm up every ``fn`` once, then ``rounds`` interleaved rounds; medians per name."""
    last = {name: fn() for name, fn in fns.items()}
    samples: dict = {name: ([], []) for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            w, c, last[name] = _timed(fn, inner)
            samples[name][0].append(w)
            samples[name][1].append(c)
    return {name: {"wall": statistics.median(ws), "cpu": statistics.median(cs),
                   "result": last[name]} for name, (ws, cs) in samples.items()}


# ------------------------------------------------------------------------------------ ladybug
def ladybug(rounds: int) -> dict:
    import fgopt
    from benchmarks.ba import ceres_cpp_run, fgopt_params, fgopt_solver, profile_iteration
    from fgopt.io import read_bal

    path = _data("bal/problem-49-7776-pre.txt")
    forms = {f: read_bal(path, form=f) for f in ("snavely", "camera", "pose+calibration")}
    out: dict = {}
    for form, (g, v) in forms.items():
        prof = profile_iteration(g, v)
        out[form] = {"iteration_cpu": prof["iteration total"], "profile": prof}

    def five(g, v):
        return lambda: fgopt.optimize(g, v, method="lm", linear_solver=fgopt_solver("schur_dense"),
                                      params=fgopt_params("5it"))

    runs = _median_runs({f: five(g, v) for f, (g, v) in forms.items()}, rounds)
    for form, (g, v) in forms.items():
        r = runs[form]
        out[form].update(five_it_wall=r["wall"], five_it_cpu=r["cpu"],
                         five_it_cost=r["result"].final_cost,
                         converged_cost=fgopt.optimize(g, v).final_cost)
    base = out["snavely"]["iteration_cpu"]
    for form in forms:
        out[form]["iteration_ratio"] = out[form]["iteration_cpu"] / base
        out[form]["five_it_cpu_ratio"] = out[form]["five_it_cpu"] / out["snavely"]["five_it_cpu"]
    ceres = ceres_cpp_run(path, "5it")
    if ceres is not None:
        out["ceres_cpp_5it"] = ceres
    return out


# ------------------------------------------------------------------------------------ stereo VO
def _gtsam_stereo_vo(paths, anchor: str):
    import gtsam
    from fgopt import key

    cal = np.loadtxt(paths[0])
    K = gtsam.Cal3_S2Stereo(*cal)
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for row in np.loadtxt(paths[1]):
        v.insert(key("x", int(row[0])), gtsam.Pose3(row[1:].reshape(4, 4)))
    model = gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
    for x, lm, uL, uR, vv, X, Y, Z in np.loadtxt(paths[2]):
        xk, lk = key("x", int(x)), key("l", int(lm))
        g.add(gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(uL, uR, vv), model, xk, lk, K))
        if not v.exists(lk):
            v.insert(lk, v.atPose3(xk).transformFrom(np.array([X, Y, Z])))
    x1 = v.atPose3(key("x", 1))
    if anchor == "equality":
        g.add(gtsam.NonlinearEqualityPose3(key("x", 1), x1))
    else:
        g.add(gtsam.PriorFactorPose3(key("x", 1), x1, gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    params = gtsam.LevenbergMarquardtParams()
    params.setOrderingType("METIS")
    return g, v, params


def stereo_vo(rounds: int) -> dict:
    import gtsam

    import fgopt
    from fgopt.io import read_stereo_vo

    paths = [_data("vision/" + n) for n in ("VO_calibration.txt", "VO_camera_poses_large.txt",
                                            "VO_stereo_factors_large.txt")]
    graph, initial, _ = read_stereo_vo(*paths)
    eq = _gtsam_stereo_vo(paths, "equality")
    pr = _gtsam_stereo_vo(paths, "prior")
    runs = _median_runs({
        "fgopt": lambda: fgopt.optimize(graph, initial),
        "gtsam (NonlinearEquality, as the example)":
            lambda: gtsam.LevenbergMarquardtOptimizer(*eq).optimize(),
        "gtsam (prior 1e-6 on x1, as fgopt)":
            lambda: gtsam.LevenbergMarquardtOptimizer(*pr).optimize()}, rounds)
    r = runs["fgopt"]["result"]
    out = {"fgopt": {"wall": runs["fgopt"]["wall"], "cpu": runs["fgopt"]["cpu"],
                     "final": r.final_cost, "iterations": r.iterations}}
    poses = [k for k in initial.keys() if k.char == "x"]
    for name, (g, _, _) in (("gtsam (NonlinearEquality, as the example)", eq),
                            ("gtsam (prior 1e-6 on x1, as fgopt)", pr)):
        est = runs[name]["result"]
        out[name] = {"wall": runs[name]["wall"], "cpu": runs[name]["cpu"],
                     "final": g.error(est),
                     "max_pose_difference": max(float(np.abs(r.values.at(k).matrix()
                                                             - est.atPose3(k).matrix()).max())
                                                for k in poses),
                     "cpu_ratio": runs[name]["cpu"] / runs["fgopt"]["cpu"]}
    return out


# ------------------------------------------------------------------------------------ SFM
def gtsam_sfm_graph(sfm, smart: bool):
    """The same SFMExample graph and initial values in GTSAM."""
    import gtsam

    from fgopt import key

    K = gtsam.Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)
    pixel = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    n_pose, n_pt = sfm.measurements.shape[:2]
    if smart:
        for j in range(n_pt):
            f = gtsam.SmartProjectionPoseFactorCal3_S2(pixel, K)
            for i in range(n_pose):
                f.add(sfm.measurements[i, j], key("x", i))
            g.add(f)
        s = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.1, 0.3, 0.3, 0.3]))
        for i in (0, 1):
            g.add(gtsam.PriorFactorPose3(key("x", i), gtsam.Pose3(sfm.truth.at(key("x", i))
                                                                  .matrix()), s))
    else:
        s = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.3, 0.3, 0.3, 0.1, 0.1, 0.1]))
        g.add(gtsam.PriorFactorPose3(key("x", 0), gtsam.Pose3(sfm.truth.at(key("x", 0)).matrix()),
                                     s))
        for i in range(n_pose):
            for j in range(n_pt):
                g.add(gtsam.GenericProjectionFactorCal3_S2(sfm.measurements[i, j], pixel,
                                                           key("x", i), key("l", j), K))
        g.add(gtsam.PriorFactorPoint3(key("l", 0), sfm.truth.at(key("l", 0)),
                                      gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
        for j in range(n_pt):
            v.insert(key("l", j), np.asarray(sfm.initial.at(key("l", j))))
    for i in range(n_pose):
        v.insert(key("x", i), gtsam.Pose3(sfm.initial.at(key("x", i)).matrix()))
    return g, v


def _sfm(rounds: int, inner: int, smart: bool) -> dict:
    import gtsam

    import fgopt
    from fgopt import key
    from fgopt.datasets import sfm_cube

    sfm = sfm_cube(smart=smart, seed=3)
    g, v = gtsam_sfm_graph(sfm, smart=smart)
    if smart:
        fns = {"fgopt": lambda: fgopt.optimize(sfm.graph, sfm.initial),
               "gtsam": lambda: gtsam.LevenbergMarquardtOptimizer(g, v).optimize()}
    else:
        fns = {"fgopt": lambda: fgopt.optimize(sfm.graph, sfm.initial, method="dogleg"),
               "gtsam": lambda: gtsam.DoglegOptimizer(g, v, gtsam.DoglegParams()).optimize()}
    runs = _median_runs(fns, rounds, inner)
    r, est = runs["fgopt"]["result"], runs["gtsam"]["result"]
    diff = max(float(np.abs(r.values.at(key("x", i)).matrix()
                            - est.atPose3(key("x", i)).matrix()).max()) for i in range(8))
    return {"fgopt": {"wall": runs["fgopt"]["wall"], "cpu": runs["fgopt"]["cpu"],
                      "final": r.final_cost, "iterations": r.iterations},
            "gtsam": {"wall": runs["gtsam"]["wall"], "cpu": runs["gtsam"]["cpu"],
                      "final": g.error(est), "max_pose_difference": diff,
                      "cpu_ratio": runs["gtsam"]["cpu"] / runs["fgopt"]["cpu"]}}


def smart_ring(num_cameras: int = 60, num_points: int = 1500, seed: int = 0):
    """A larger smart-factor problem: cameras on a circle (radius 40 m, heights +-2 m) looking at
    the centre, points uniform in a 20 m cube, each seen by 3-10 consecutive cameras with
    0.5-pixel noise; initial poses perturbed (0.005 rad, 0.05 m); priors on the first two poses.
    Returns the fgopt graph / values and the GTSAM graph / values."""
    import gtsam

    import fgopt
    from fgopt import PriorFactor, key
    from fgopt.cameras import Cal3_S2, PinholeCamera, SmartProjectionFactor
    from fgopt.noise import Isotropic

    rng = np.random.default_rng(seed)
    K = Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0)
    GK = gtsam.Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0)
    angles = np.linspace(0.0, 2.0 * np.pi, num_cameras, endpoint=False)
    poses = [PinholeCamera.lookat([40 * np.cos(t), 40 * np.sin(t), rng.uniform(-2, 2)],
                                  np.zeros(3), [0, 0, 1], K).pose() for t in angles]
    pts = rng.uniform(-10.0, 10.0, size=(num_points, 3))
    g, v = fgopt.FactorGraph(), fgopt.Variables()
    gg, gv = gtsam.NonlinearFactorGraph(), gtsam.Values()
    pixel, gpixel = Isotropic.sigma(2, 0.5), gtsam.noiseModel.Isotropic.Sigma(2, 0.5)
    for j in range(num_points):
        m = int(rng.integers(3, 11))
        start = int(rng.integers(num_cameras))
        views = [(start + q) % num_cameras for q in range(m)]
        z = np.array([PinholeCamera(poses[i], K).project(pts[j]) for i in views])
        z += rng.normal(size=z.shape) * 0.5
        g.add(SmartProjectionFactor([key("x", i) for i in views], z, K, pixel))
        f = gtsam.SmartProjectionPoseFactorCal3_S2(gpixel, GK)
        for i, zz in zip(views, z):
            f.add(zz, key("x", i))
        gg.add(f)
    prior = Isotropic.sigma(6, 1e-3)
    for i in (0, 1):
        g.add(PriorFactor(key("x", i), poses[i], prior))
        gg.add(gtsam.PriorFactorPose3(key("x", i), gtsam.Pose3(poses[i].matrix()),
                                      gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    for i, p in enumerate(poses):
        d = np.concatenate([rng.normal(size=3) * 0.005, rng.normal(size=3) * 0.05])
        x0 = p.retract(d) if i > 1 else p
        v.add(key("x", i), x0)
        gv.insert(key("x", i), gtsam.Pose3(x0.matrix()))
    return g, v, gg, gv


def smart_large(rounds: int) -> dict:
    import gtsam

    import fgopt
    from fgopt import key

    g, v, gg, gv = smart_ring()
    runs = _median_runs({"fgopt": lambda: fgopt.optimize(g, v),
                         "gtsam": lambda: gtsam.LevenbergMarquardtOptimizer(gg, gv).optimize()},
                        rounds)
    r, est = runs["fgopt"]["result"], runs["gtsam"]["result"]
    n = len([k for k in v.keys() if k.char == "x"])
    diff = max(float(np.abs(r.values.at(key("x", i)).matrix()
                            - est.atPose3(key("x", i)).matrix()).max()) for i in range(n))
    return {"fgopt": {"wall": runs["fgopt"]["wall"], "cpu": runs["fgopt"]["cpu"],
                      "final": r.final_cost, "iterations": r.iterations},
            "gtsam": {"wall": runs["gtsam"]["wall"], "cpu": runs["gtsam"]["cpu"],
                      "final": gg.error(est), "max_pose_difference": diff,
                      "cpu_ratio": runs["gtsam"]["cpu"] / runs["fgopt"]["cpu"]}}


# ------------------------------------------------------------------------------------ report
def _fmt(x, spec="{:.4g}"):
    return spec.format(x) if isinstance(x, (int, float)) else str(x)


def report(res: dict) -> str:
    lines = []
    if "ladybug" in res:
        lb = res["ladybug"]
        lines += ["## Ladybug-49 (CPU seconds; ratio = form / 9-vector Snavely kernel)", "",
                  "| form | 1 LM iteration | ratio | 5 it CPU | ratio | 5 it wall | 5 it cost |"
                  " converged cost |", "|---|---|---|---|---|---|---|---|"]
        for form in ("snavely", "camera", "pose+calibration"):
            f = lb[form]
            lines.append(f"| {form} | {_fmt(f['iteration_cpu'])} | {f['iteration_ratio']:.2f} | "
                         f"{_fmt(f['five_it_cpu'])} | {f['five_it_cpu_ratio']:.2f} | "
                         f"{_fmt(f['five_it_wall'])} | {f['five_it_cost']:.6g} | "
                         f"{f['converged_cost']:.6g} |")
        if "ceres_cpp_5it" in lb:
            c = lb["ceres_cpp_5it"]
            lines.append(f"| C++ Ceres (9-vector, SPARSE_SCHUR) | | | {_fmt(c['cpu'])} | "
                         f"{c['cpu'] / lb['snavely']['five_it_cpu']:.2f} | {_fmt(c['wall'])} | "
                         f"{c['final']:.6g} | |")
        lines.append("")
    for sec, title in (("stereo_vo", "StereoVOExample_large"), ("smart_sfm", "Smart-factor SFM"),
                       ("smart_large", "Smart factors, 60 cameras x 1500 tracks of 3-10 views"),
                       ("sfm", "SFMExample (projection factors, Dogleg)")):
        if sec not in res:
            continue
        lines += [f"## {title} (seconds; ratio = peer CPU / fgopt CPU, > 1: fgopt faster)", "",
                  "| library | CPU | wall | final cost | max pose difference to fgopt | ratio |",
                  "|---|---|---|---|---|---|"]
        for name, r in res[sec].items():
            lines.append(f"| {name} | {_fmt(r['cpu'])} | {_fmt(r['wall'])} | {r['final']:.8g} | "
                         f"{_fmt(r.get('max_pose_difference', ''), '{:.2g}')} | "
                         f"{_fmt(r.get('cpu_ratio', ''), '{:.2f}')} |")
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sections", default=",".join(SECTIONS))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--inner", type=int, default=20, help="solves per sample of the SFM scenes")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    res: dict = {}
    for sec in a.sections.split(","):
        if sec == "ladybug":
            res[sec] = ladybug(a.rounds)
        elif sec == "stereo_vo":
            res[sec] = stereo_vo(a.rounds)
        elif sec == "smart_sfm":
            res[sec] = _sfm(a.rounds, a.inner, smart=True)
        elif sec == "smart_large":
            res[sec] = smart_large(a.rounds)
        elif sec == "sfm":
            res[sec] = _sfm(a.rounds, a.inner, smart=False)
        else:
            raise SystemExit(f"unknown section {sec!r}; choose from {', '.join(SECTIONS)}")
    print(report(res))
    print(f"load average {os.getloadavg()[0]:.2f}")
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
