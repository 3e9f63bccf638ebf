"""Bundler .out reader and the GTSAM camera forms of BAL problems: same initial cost and poses as
GTSAM's SfmData, the same optimum in every form, errors naming file:line."""

from __future__ import annotations

import numpy as np
import pytest

import fgopt
from fgopt import key
from fgopt.cameras import Cal3Bundler, PinholeCamera
from fgopt.errors import FgoptError, FileFormatError
from fgopt.io import read_bal, read_bundler

BALBIANELLO = "vision/Balbianello.out"
FORMS = ("camera", "pose+calibration", "pose")


def _gtsam_sfm_problem(path, from_bal=False):
    """GTSAM's graph of GeneralSFMFactorCal3Bundler over SfmData (no priors) and its values."""
    import gtsam

    sfm = (gtsam.SfmData.FromBalFile if from_bal else gtsam.SfmData.FromBundlerFile)(str(path))
    gg, gv = gtsam.NonlinearFactorGraph(), gtsam.Values()
    noise = gtsam.noiseModel.Unit.Create(2)
    for j in range(sfm.numberTracks()):
        tr = sfm.track(j)
        for k in range(tr.numberMeasurements()):
            i, uv = tr.measurement(k)
            gg.add(gtsam.GeneralSFMFactorCal3Bundler(uv, noise, key("c", i), key("p", j)))
        gv.insert(key("p", j), tr.point3())
    for i in range(sfm.numberCameras()):
        gv.insert(key("c", i), sfm.camera(i))
    return sfm, gg, gv


def test_balbianello_equals_gtsam_sfmdata(data_file):
    """Balbianello.out: 5 cameras, 544 points, 1417 observations; poses, calibrations and the
    initial cost equal GTSAM's SfmData.FromBundlerFile (which parses floats in single precision,
    hence 1e-6), and the optimum equals GTSAM's LM optimum (relative 1e-6)."""
    gtsam = pytest.importorskip("gtsam")
    path = data_file(BALBIANELLO)
    g, v = read_bundler(path)
    assert len(g) == 1417 and len(v.keys()) == 5 + 544
    sfm, gg, gv = _gtsam_sfm_problem(path)
    for i in range(5):
        cam = v.at(key("c", i))
        assert isinstance(cam, PinholeCamera) and isinstance(cam.calibration(), Cal3Bundler)
        np.testing.assert_allclose(cam.pose().matrix(), sfm.camera(i).pose().matrix(), atol=1e-6)
        K = sfm.camera(i).calibration()  # (its vector() binding is Cal3f's in GTSAM 4.3)
        np.testing.assert_allclose(cam.calibration().vector(), [K.fx(), K.k1(), K.k2()],
                                   rtol=1e-6)
    assert g.error(v) == pytest.approx(gg.error(gv), rel=1e-8)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-10)
    ref = gg.error(gtsam.LevenbergMarquardtOptimizer(gg, gv, params).optimize())
    r = fgopt.optimize(g, v, relative_tolerance=1e-10, absolute_tolerance=1e-10)
    assert r.final_cost == pytest.approx(ref, rel=1e-6)


def test_bundler_forms_agree(data_file):
    """The three forms have the same initial cost; the camera and pose+calibration forms reach
    the same optimum (relative 1e-8)."""
    path = data_file(BALBIANELLO)
    costs, finals = [], []
    for form in FORMS:
        g, v = read_bundler(path, form=form)
        costs.append(g.error(v))
        if form != "pose":
            finals.append(fgopt.optimize(g, v, relative_tolerance=1e-10,
                                         absolute_tolerance=1e-10).final_cost)
    np.testing.assert_allclose(costs, costs[0], rtol=1e-13)
    assert finals[0] == pytest.approx(finals[1], rel=1e-8)


def test_bal_gtsam_forms_equal_the_snavely_cost(data_file):
    """dubrovnik-3-7: the GTSAM forms of a BAL file have the Snavely form's cost to 1e-12, and
    GTSAM's SfmData.FromBalFile graph's (single-precision parse, 1e-6)."""
    pytest.importorskip("gtsam")
    path = data_file("bal/dubrovnik-3-7-pre.txt")
    g0, v0 = read_bal(path)
    ref = g0.error(v0)
    for form in FORMS:
        g, v = read_bal(path, form=form)
        assert g.error(v) == pytest.approx(ref, rel=1e-12)
    _, gg, gv = _gtsam_sfm_problem(path, from_bal=True)
    assert gg.error(gv) == pytest.approx(ref, rel=1e-6)


def test_ladybug_both_forms_reach_the_same_cost(data_file):
    """Ladybug-49 (31 observations behind a camera at the start, counted in both forms): the
    9-vector Snavely form and the PinholeCamera (SE3 + Cal3Bundler) form start at the same cost
    and converge to the same final cost (relative 1e-6; BAL's reference optimum 13344.3)."""
    path = data_file("bal/problem-49-7776-pre.txt")
    finals = []
    for form in ("snavely", "camera"):
        g, v = read_bal(path, form=form)
        assert g.error(v) == pytest.approx(850912.4606807708, rel=1e-12)
        finals.append(fgopt.optimize(g, v).final_cost)
    assert finals[1] == pytest.approx(finals[0], rel=1e-6)
    assert finals[0] == pytest.approx(13344.3, rel=1e-5)


_GOOD = """# Bundle file v0.3
2 1
500 0.1 0.01
1 0 0
0 1 0
0 0 1
0 0 -5
510 0 0
1 0 0
0 1 0
0 0 1
1 0 -5
0.1 0.2 0.3
255 0 0
2 0 5 10.0 -3.0 1 7 -90.0 -3.0
"""


def _bad(old: str, new: str) -> bytes:
    assert old in _GOOD
    return _GOOD.replace(old, new, 1).encode()


def test_small_file_and_malformed_input_named_by_line(tmp_path):
    """A hand-written file reads (points in front: finite cost); a non-positive focal length,
    a non-rotation, a camera index out of range, a NaN, a truncated file and an unknown form
    raise FileFormatError / FgoptError naming the file and line."""
    g, v = read_bundler("mem.out", data=_GOOD.encode())
    assert len(g) == 2 and np.isfinite(g.error(v))
    cases = [(_bad("510 0 0", "0 0 0"), r"mem.out:8: camera 1: focal length 0"),
             (_bad("0 1 0\n0 0 1\n1 0 -5", "0 2 0\n0 0 1\n1 0 -5"), r"mem.out:9: camera 1: R"),
             (_bad("1 7 -90.0", "2 7 -90.0"), r"mem.out:15: camera index 2 is out of range"),
             (_bad("10.0 -3.0", "nan -3.0"), r"mem.out:15: 'nan' is not a finite number"),
             (_GOOD[:-30].encode(), r"mem.out:\d+: point 0: 2 views announced")]
    for data, msg in cases:
        with pytest.raises(FileFormatError, match=msg):
            read_bundler("mem.out", data=data)
    with pytest.raises(FgoptError, match="form"):
        read_bundler("mem.out", data=_GOOD.encode(), form="snavely")
    p = tmp_path / "x.out"
    p.write_text(_GOOD)
    assert read_bundler(p, form="pose")[0].error(read_bundler(p, form="pose")[1]) == \
        pytest.approx(g.error(v), rel=1e-14)


def test_read_detects_bundler_files(data_file):
    """fgopt.io.read recognizes the '# Bundle file' header and returns the camera form."""
    from fgopt.io import detect_format, read

    path = data_file(BALBIANELLO)
    assert detect_format(path) == "bundler"
    g, v = read(path)
    g2, v2 = read_bundler(path)
    assert len(g) == len(g2) and g.error(v) == g2.error(v2)


def test_threaded_linearization_matches_serial(data_file):
    """threads=2 (the camera kernels release the GIL) reaches the serial path's cost."""
    g, v = read_bundler(data_file(BALBIANELLO))
    serial = fgopt.optimize(g, v, max_iterations=3).final_cost
    assert fgopt.optimize(g, v, max_iterations=3, threads=2).final_cost == pytest.approx(
        serial, rel=1e-10)
