"""GTSAM ``load2D`` files: noise formats (GTSAM's auto rule, iSAM's square-root information),
LANDMARK -> bearing-range with GTSAM's sigmas, chained initial values, errors with file:line,
and Victoria Park read exactly as GTSAM reads it (same cost at the same values)."""

from __future__ import annotations

import numpy as np
import pytest

from fgopt import key
from fgopt.errors import FgoptError, FileFormatError
from fgopt.io import detect_format, load2d, parse_load2d, read
from fgopt.manifolds import SE2

TEXT = """ODOMETRY 0 1 1.0 0.0 0.1 0.0001 0 0 4e-06 0 4e-06
LANDMARK 1 5 3.0 4.0 0.4 0 0.4
ODOMETRY 1 2 1.0 0.5 -0.2 0.0001 0 0 4e-06 0 4e-06
BR 2 5 0.3 5.0 0.1 0.2
"""


def test_victoria_style_records(tmp_path):
    """COV noise guessed as GTSAM does, landmarks placed at first sighting, keys x/l."""
    p = tmp_path / "vp.txt"
    p.write_text(TEXT)
    assert detect_format(p) == "load2d"
    g, v = read(p)
    assert len(g) == 4 and sorted(v.keys()) == sorted([key("x", 0), key("x", 1), key("x", 2),
                                                        key("l", 5)])
    # covariance diag(1e-4, 4e-6, 4e-6) in (x, y, theta): sqrt-information in (theta, x, y)
    R = g[0].noise.sqrt_information
    assert np.allclose(np.diag(R), [1 / 2e-3, 1 / 1e-2, 1 / 2e-3])
    # LANDMARK: range 5, bearing atan2(4, 3); sigmas sqrt(0.4 / 10), sqrt(0.4) (range first)
    f = g[1]
    assert np.allclose(f.constants, [5.0, np.arctan2(4.0, 3.0)])
    assert np.allclose(np.diag(f.noise.sqrt_information), [1 / np.sqrt(0.4), 1 / np.sqrt(0.04)])
    x1 = v.at(key("x", 1))
    assert np.allclose(v.at(key("l", 5)), x1.act(np.array([3.0, 4.0])))
    assert v.at(key("x", 2)).equals(x1 * SE2.from_xytheta(1.0, 0.5, -0.2))


def test_noise_formats(tmp_path):
    """The same numbers read as iSAM square-root information, g2o and TORO information."""
    p = tmp_path / "w.txt"
    p.write_text("EDGE2 0 1 1 0 0 3 0.5 0.25 2 0.1 5\n")
    R = parse_load2d(p, "sqrt_information").edge_sqrt_info[0]
    file_R = np.array([[3, 0.5, 0.25], [0, 2, 0.1], [0, 0, 5]])
    perm = [2, 0, 1]
    assert np.allclose(R.T @ R, (file_R.T @ file_R)[np.ix_(perm, perm)])
    I_g2o = np.array([[3, 0.5, 0.25], [0.5, 2, 0.1], [0.25, 0.1, 5]])
    R = parse_load2d(p, "g2o").edge_sqrt_info[0]
    assert np.allclose(R.T @ R, I_g2o[np.ix_(perm, perm)])
    I_toro = np.array([[3, 0.5, 0.1], [0.5, 0.25, 5], [0.1, 5, 2]])
    with pytest.raises(FgoptError, match="w.txt:1.*positive definite"):
        parse_load2d(p, "toro")          # TORO order makes this matrix indefinite
    assert np.linalg.eigvalsh(I_toro)[0] < 0
    with pytest.raises(FgoptError, match="w.txt:1.*guess"):
        parse_load2d(p)                  # neither of GTSAM's two zero patterns


def test_errors_name_file_and_line(tmp_path):
    p = tmp_path / "bad.txt"
    p.write_text("ODOMETRY 0 1 1 0 0 1 0 0 1 0 1\nLANDMARK 1 2 3.0\n")
    with pytest.raises(FileFormatError, match="bad.txt:2"):
        parse_load2d(p)
    p.write_text("ODOMETRY 0 1 1 0 0 1 0 0 1 0 1\nPOINT3 1 2 3 4 5\n")
    with pytest.raises(FileFormatError, match="bad.txt:2.*POINT3"):
        parse_load2d(p)


def test_victoria_park_matches_gtsam(data_file):
    """Victoria Park: the same factors as GTSAM's load2D (equal cost at GTSAM's values)."""
    gtsam = pytest.importorskip("gtsam")
    path = data_file("slam/victoria_park.txt")
    g, v = load2d(path)
    gg, gv = gtsam.load2D(str(path))
    assert len(g) == gg.size() == 10608 and len(v) == gv.size() == 7120
    assert g.error(v) == pytest.approx(gg.error(gv), rel=1e-12)
