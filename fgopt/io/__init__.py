"""Read and write factor-graph files: g2o / TORO pose graphs and BAL bundle adjustment.

``read(path)`` picks the reader by content (and extension); ``read_g2o`` / ``write_g2o``,
``read_bal`` / ``write_bal`` are the specific entries. Errors are :class:`fgopt.errors.FileFormatError`
naming the file and line.
"""

from .g2o import FIX_SIGMA as FIX_SIGMA
from .g2o import read_g2o as read_g2o
from .g2o_write import write_g2o as write_g2o
