"""Side-by-side benchmarks of fgopt against GTSAM, Ceres (pyceres), SymForce and scipy.

Run ``python -m benchmarks.run --help``; the protocol is in ``benchmarks/README.md``.
"""
