"""Read and write factor-graph files: g2o / TORO pose graphs, BAL and Bundler bundle adjustment,
and 2-D SLAM files in GTSAM's ``load2D`` formats (Victoria Park's ``ODOMETRY`` / ``LANDMARK``).

``read(path)`` picks the reader by content (and extension); ``read_g2o`` / ``write_g2o``,
``read_bal`` / ``write_bal`` and ``load2d`` / ``parse_load2d`` are the specific entries. Malformed input raises
:class:`fgopt.errors.FileFormatError` naming the file and line. Log messages (initial guesses,
repairs, skipped lines) go to the ``fgopt.io`` logger.
"""

from .bal import read_bal as read_bal
from .bal import reprojection_kernel as reprojection_kernel
from .bal import write_bal as write_bal
from .bal import write_bal_arrays as write_bal_arrays
from .bundler import read_bundler as read_bundler
from .dispatch import detect_format as detect_format
from .dispatch import read as read
from .g2o import FIX_SIGMA as FIX_SIGMA
from .g2o import add_gauge_prior as add_gauge_prior
from .g2o import read_g2o as read_g2o
from .g2o_write import write_g2o as write_g2o
from .load2d import load2d as load2d
from .load2d import parse_load2d as parse_load2d
from .stereo_vo import read_stereo_vo as read_stereo_vo
