"""Camera calibrations (intrinsics): GTSAM's models plus the double sphere.

Each class is an immutable value and a vector-space manifold (``retract(d) = k + d``,
``local(a, b) = b - a`` on the parameters), registered with fgopt so a calibration can be a
variable (self-calibration) with its own batch kind. Constructors take GTSAM's parameter order:

* ``Cal3_S2(fx, fy, s, u0, v0)`` - pinhole with skew;
* ``Cal3DS2(fx, fy, s, u0, v0, k1, k2, p1=0, p2=0)`` - radial + tangential (Brown-Conrady);
* ``Cal3Bundler(f, k1, k2, u0=0, v0=0)`` - Snavely/Bundler; tangent ``(f, k1, k2)`` only;
* ``Cal3Fisheye(fx, fy, s, u0, v0, k1, k2, k3, k4)`` - Kannala-Brandt / OpenCV fisheye;
* ``Cal3Unified(fx, fy, s, u0, v0, k1, k2, p1=0, p2=0, xi=0)`` - Mei's unified model;
* ``DoubleSphere(fx, fy, cx, cy, xi, alpha)`` - Usenko et al. 2018 (not in GTSAM);
* ``Cal3_S2Stereo(fx, fy, s, u0, v0, b)`` - a rectified stereo pair with baseline ``b``.

``uncalibrate(xy)`` maps intrinsic (normalized-plane) coordinates to pixels and ``calibrate(uv)``
back, for one point ``(2,)`` or many ``(n, 2)``; ``jacobians=True`` also returns
``(D_k, D_xy)`` (``(2, dim)``/``(2, 2)`` per point). The shared base
class is in :mod:`fgopt.cameras._calibration_base`, the math in
:mod:`fgopt.cameras._calib_kernels`.
"""

from __future__ import annotations

from ..errors import CalibrationError
from . import _calib_kernels as CK
from ._calibration_base import CALIBRATE_MAX_ITERATIONS as CALIBRATE_MAX_ITERATIONS
from ._calibration_base import CALIBRATE_TOL as CALIBRATE_TOL
from ._calibration_base import Calibration as Calibration
from ._calibration_base import as_points2 as as_points2
from ._calibration_base import register_models


class Cal3_S2(Calibration):
    """Pinhole ``u = fx x + s y + u0``, ``v = fy y + v0``. Storage = tangent
    ``(fx, fy, s, u0, v0)``.

    Example:

    >>> from fgopt.cameras import Cal3_S2
    >>> K = Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0)
    >>> K.uncalibrate(np.array([0.1, -0.2]))
    array([370., 140.])
    >>> K.calibrate(np.array([370.0, 140.0]))
    array([ 0.1, -0.2])
    """

    __slots__ = ()
    MODEL = CK.CAL3_S2
    PARAMS = ("fx", "fy", "s", "u0", "v0")
    DIM = 5

    def __init__(self, fx: float, fy: float, s: float, u0: float, v0: float):
        super().__init__(fx, fy, s, u0, v0)


class Cal3DS2(Calibration):
    """Brown-Conrady: ``g = 1 + k1 r^2 + k2 r^4``, ``pn = g (x, y) + (2 p1 xy + p2 (r^2 + 2x^2),
    2 p2 xy + p1 (r^2 + 2y^2))``, then the pinhole. Storage = tangent
    ``(fx, fy, s, u0, v0, k1, k2, p1, p2)``.

    >>> from fgopt.cameras import Cal3DS2
    >>> K = Cal3DS2(500.0, 500.0, 0.0, 320.0, 240.0, 0.1, 0.01, 0.001, 0.002)
    >>> uv = K.uncalibrate(np.array([0.1, -0.2]))     # normalized image point -> pixels
    >>> np.round(uv, 4), K.dim()
    (array([370.3012, 139.5225]), 9)
    >>> np.round(K.calibrate(uv), 9)                  # and back
    array([ 0.1, -0.2])
    """

    __slots__ = ()
    MODEL = CK.CAL3DS2
    PARAMS = ("fx", "fy", "s", "u0", "v0", "k1", "k2", "p1", "p2")
    DIM = 9

    def __init__(self, fx: float, fy: float, s: float, u0: float, v0: float, k1: float,
                 k2: float, p1: float = 0.0, p2: float = 0.0):
        super().__init__(fx, fy, s, u0, v0, k1, k2, p1, p2)

    def k1(self) -> float:
        return float(self._data[5])

    def k2(self) -> float:
        return float(self._data[6])

    def p1(self) -> float:
        return float(self._data[7])

    def p2(self) -> float:
        return float(self._data[8])


class Cal3Bundler(Calibration):
    """Bundler / BAL: ``u = u0 + f g x``, ``g = 1 + k1 r^2 + k2 r^4``. Storage
    ``(f, k1, k2, u0, v0)``, tangent ``(f, k1, k2)``: the principal point is not optimized
    (GTSAM's ``Cal3Bundler``, dimension 3).

    >>> K = fgopt.cameras.Cal3Bundler(500.0, 0.1, 0.01, 320.0, 240.0)   # f, k1, k2, u0, v0
    >>> np.round(K.uncalibrate([0.1, -0.2]), 4), np.round(K.calibrate([370.2513, 139.4975]), 4)
    (array([370.2513, 139.4975]), array([ 0.1, -0.2]))
    """

    __slots__ = ()
    MODEL = CK.CAL3BUNDLER
    PARAMS = ("f", "k1", "k2", "u0", "v0")
    DIM = 3

    def __init__(self, f: float, k1: float, k2: float, u0: float = 0.0, v0: float = 0.0):
        super().__init__(f, k1, k2, u0, v0)

    def fy(self) -> float:
        return float(self._data[0])

    def skew(self) -> float:
        return 0.0

    def px(self) -> float:
        return float(self._data[3])

    def py(self) -> float:
        return float(self._data[4])

    def k1(self) -> float:
        return float(self._data[1])

    def k2(self) -> float:
        return float(self._data[2])


class Cal3Fisheye(Calibration):
    """Kannala-Brandt: ``theta = atan(r)``, ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 +
    k3 theta^6 + k4 theta^8)``, ``(xd, yd) = theta_d / r (x, y)``, then the pinhole. Storage =
    tangent ``(fx, fy, s, u0, v0, k1, k2, k3, k4)``.

    >>> from fgopt.cameras import Cal3Fisheye
    >>> K = Cal3Fisheye(500.0, 500.0, 0.0, 320.0, 240.0, 0.1, 0.01, 0.0, 0.0)
    >>> uv = K.uncalibrate(np.array([0.1, -0.2]))     # normalized image point -> pixels
    >>> np.round(uv, 4), K.dim()
    (array([369.43, 141.14]), 9)
    >>> np.round(K.calibrate(uv), 9)                  # and back
    array([ 0.1, -0.2])
    """

    __slots__ = ()
    MODEL = CK.CAL3FISHEYE
    PARAMS = ("fx", "fy", "s", "u0", "v0", "k1", "k2", "k3", "k4")
    DIM = 9

    def __init__(self, fx: float, fy: float, s: float, u0: float, v0: float, k1: float,
                 k2: float, k3: float, k4: float):
        super().__init__(fx, fy, s, u0, v0, k1, k2, k3, k4)

    def k1(self) -> float:
        return float(self._data[5])

    def k2(self) -> float:
        return float(self._data[6])

    def k3(self) -> float:
        return float(self._data[7])

    def k4(self) -> float:
        return float(self._data[8])


class Cal3Unified(Calibration):
    """Mei's unified model: ``m = (x, y) / (1 + xi |(x, y, 1)|)``, then Cal3DS2. Storage =
    tangent ``(fx, fy, s, u0, v0, k1, k2, p1, p2, xi)``, ``xi >= 0``.

    >>> from fgopt.cameras import Cal3Unified
    >>> K = Cal3Unified(500.0, 500.0, 0.0, 320.0, 240.0, 0.1, 0.01, 0.0, 0.0, 0.5)
    >>> uv = K.uncalibrate(np.array([0.1, -0.2]))     # normalized image point -> pixels
    >>> np.round(uv, 4), K.dim()
    (array([353.1336, 173.7328]), 10)
    >>> np.round(K.calibrate(uv), 9)                  # and back
    array([ 0.1, -0.2])
    """

    __slots__ = ()
    MODEL = CK.CAL3UNIFIED
    PARAMS = ("fx", "fy", "s", "u0", "v0", "k1", "k2", "p1", "p2", "xi")
    DIM = 10

    def __init__(self, fx: float, fy: float, s: float, u0: float, v0: float, k1: float,
                 k2: float, p1: float = 0.0, p2: float = 0.0, xi: float = 0.0):
        super().__init__(fx, fy, s, u0, v0, k1, k2, p1, p2, xi)

    @classmethod
    def _check(cls, data: np.ndarray) -> None:
        super()._check(data)
        # xi is the distance from the unit sphere's centre to the projection centre (Mei and
        # Rives 2007; 0: pinhole, 1: parabolic mirror, > 1: fisheye), never negative
        if not data[9] >= 0.0:
            raise CalibrationError(f"Cal3Unified: xi must be >= 0, got {data[9]:g}")

    def xi(self) -> float:
        return float(self._data[9])


class DoubleSphere(Calibration):
    """Double sphere (Usenko, Demmel, Cremers, 3DV 2018), of the ray ``(x, y, 1)``:
    ``d1 = |(x, y, 1)|``, ``w = xi d1 + 1``, ``d2 = |(x, y, w)|``,
    ``(u, v) = (fx x, fy y) / (alpha d2 + (1 - alpha) w) + (cx, cy)``.
    Storage = tangent ``(fx, fy, cx, cy, xi, alpha)``, ``xi`` in ``[-1, 1]``, ``alpha`` in
    ``[0, 1]``. ``calibrate`` is the paper's closed-form unprojection. Not a GTSAM model.

    >>> from fgopt.cameras import DoubleSphere
    >>> K = DoubleSphere(300.0, 300.0, 320.0, 240.0, -0.2, 0.6)  # fx, fy, cx, cy, xi, alpha
    >>> uv = K.uncalibrate(np.array([0.1, -0.2]))     # normalized image point -> pixels
    >>> np.round(uv, 4), K.dim()
    (array([356.8746, 166.2508]), 6)
    >>> np.round(K.calibrate(uv), 9)                  # and back
    array([ 0.1, -0.2])
    """

    __slots__ = ()
    MODEL = CK.DOUBLESPHERE
    PARAMS = ("fx", "fy", "cx", "cy", "xi", "alpha")
    DIM = 6

    def __init__(self, fx: float, fy: float, cx: float, cy: float, xi: float, alpha: float):
        super().__init__(fx, fy, cx, cy, xi, alpha)

    @classmethod
    def _check(cls, data: np.ndarray) -> None:
        super()._check(data)
        # the authors' range (basalt): with |xi| > 1 unprojection fails inside the image
        if not -1.0 <= data[4] <= 1.0:
            raise CalibrationError(f"DoubleSphere: xi must be in [-1, 1], got {data[4]:g}")
        if not 0.0 <= data[5] <= 1.0:
            raise CalibrationError(f"DoubleSphere: alpha must be in [0, 1], got {data[5]:g}")

    def skew(self) -> float:
        return 0.0

    def px(self) -> float:
        return float(self._data[2])

    def py(self) -> float:
        return float(self._data[3])

    def xi(self) -> float:
        return float(self._data[4])

    def alpha(self) -> float:
        return float(self._data[5])


class Cal3_S2Stereo(Calibration):
    """A rectified stereo pair: both images share ``Cal3_S2(fx, fy, s, u0, v0)``; the right
    camera sits ``b`` along the left camera's x axis. Storage = tangent
    ``(fx, fy, s, u0, v0, b)``.

    >>> fgopt.cameras.Cal3_S2Stereo(500.0, 500.0, 0.0, 320.0, 240.0, 0.2).baseline()
    0.2
    """

    __slots__ = ()
    MODEL = CK.CAL3_S2STEREO
    PARAMS = ("fx", "fy", "s", "u0", "v0", "b")
    DIM = 6

    def __init__(self, fx: float, fy: float, s: float, u0: float, v0: float, b: float):
        super().__init__(fx, fy, s, u0, v0, b)

    @classmethod
    def _check(cls, data: np.ndarray) -> None:
        super()._check(data)
        if not data[5] > 0.0:
            raise CalibrationError(f"Cal3_S2Stereo: baseline b must be positive, got {data[5]:g}")

    def baseline(self) -> float:
        return float(self._data[5])

    def calibration(self) -> Cal3_S2:
        return Cal3_S2(*self._data[:5])


MODELS: tuple[type[Calibration], ...] = (Cal3_S2, Cal3DS2, Cal3Bundler, Cal3Fisheye,
                                         Cal3Unified, DoubleSphere, Cal3_S2Stereo)

register_models(MODELS)
