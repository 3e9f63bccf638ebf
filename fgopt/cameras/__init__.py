"""Cameras and structure from motion: calibrations, cameras, projection / stereo / smart factors,
triangulation.

Conventions are GTSAM's (so ports are mechanical): a camera pose is ``world_T_camera`` (an
:class:`~fgopt.manifolds.SE3`), the camera looks along +z with x right and y down; calibrations
take GTSAM's parameter order; residuals are ``predicted - measured`` pixels.
"""

from .calibration import Cal3_S2 as Cal3_S2
from .calibration import Cal3_S2Stereo as Cal3_S2Stereo
from .calibration import Cal3Bundler as Cal3Bundler
from .calibration import Cal3DS2 as Cal3DS2
from .calibration import Cal3Fisheye as Cal3Fisheye
from .calibration import Cal3Unified as Cal3Unified
from .calibration import Calibration as Calibration
from .calibration import DoubleSphere as DoubleSphere
from .camera import PinholeCamera as PinholeCamera
from .camera import StereoCamera as StereoCamera
from .factors import GeneralSFMFactor as GeneralSFMFactor
from .factors import ProjectionFactor as ProjectionFactor
from .factors import camera_projection_kernel as camera_projection_kernel
from .factors import StereoFactor as StereoFactor
from .factors import projection_kernel as projection_kernel
from .factors import stereo_kernel as stereo_kernel
from .triangulation import triangulate as triangulate
from .smart import SmartProjectionFactor as SmartProjectionFactor
from .smart import smart_kernel as smart_kernel

#: The public names (each has an entry in the API reference: tests/test_docs_reference.py).
__all__ = ["Cal3_S2", "Cal3_S2Stereo", "Cal3Bundler", "Cal3DS2", "Cal3Fisheye", "Cal3Unified",
           "Calibration", "DoubleSphere", "PinholeCamera", "StereoCamera", "GeneralSFMFactor",
           "ProjectionFactor", "camera_projection_kernel", "StereoFactor", "projection_kernel",
           "stereo_kernel", "triangulate", "SmartProjectionFactor", "smart_kernel"]
