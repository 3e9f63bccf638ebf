"""Read and write factor-graph files: g2o / TORO pose graphs, BAL and Bundler bundle adjustment,
and 2-D SLAM files in GTSAM's ``load2D`` formats (Victoria Park's ``ODOMETRY`` / ``LANDMARK``).

``read(path)`` picks the reader by content (and extension); ``read_g2o`` / ``write_g2o``,
``read_bal`` / ``write_bal`` and ``load2d`` / ``parse_load2d`` are the specific entries.
Malformed input raises :class:`fgopt.errors.FileFormatError` naming the file and line. Log
messages (initial guesses, repairs, skipped lines) go to the ``fgopt.io`` logger.
"""

from .dispatch import detect_format as detect_format
from .dispatch import read as read
from .g2o import FIX_SIGMA as FIX_SIGMA
from .g2o import add_gauge_prior as add_gauge_prior
from .g2o import read_g2o as read_g2o
from .g2o_write import write_g2o as write_g2o

# The other formats' modules load on first use: a g2o solve does not pay for the cameras
# package (BAL, Bundler, stereo VO) or the load2D parser (~4 ms of a new process).
_LAZY = {
    "read_bal": ".bal", "reprojection_kernel": ".bal", "write_bal": ".bal",
    "write_bal_arrays": ".bal", "read_bundler": ".bundler", "load2d": ".load2d",
    "parse_load2d": ".load2d", "read_stereo_vo": ".stereo_vo",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'fgopt.io' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))

#: The public names (each has an entry in the API reference: tests/test_docs_reference.py).
__all__ = ["detect_format", "read", "FIX_SIGMA", "add_gauge_prior", "read_g2o", "write_g2o",
           "read_bal", "reprojection_kernel", "write_bal", "write_bal_arrays", "read_bundler",
           "load2d", "parse_load2d", "read_stereo_vo"]
