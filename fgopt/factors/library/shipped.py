"""Generated kernel source of the built-in factors, shipped inside the package.

A built-in factor type (between / prior on SO2, SE2, SO3, SE3, R2, R3; the BAL reprojection)
would otherwise be derived by SymPy the first time a fresh install uses it (0.5-6 s each).
Their generated modules live in ``_shipped_kernels/<module name>.py.txt``, named by the same
cache key the kernel cache uses (function source, pattern, options, fgopt's version and the
sources of the code generator): :meth:`FactorType._module` copies a shipped source into the
kernel cache instead of deriving it. Any change to a factor or to the generator changes the key,
so a stale file is simply not found (and ``tests/factors/test_shipped.py`` fails until the files
are regenerated).

Regenerate (the test checks the committed bytes equal a fresh run)::

    python -m fgopt.factors.library.shipped

The derivative engines iterate SymPy's symbol sets, whose order follows Python's per-process
string hash seed: the script re-runs itself with ``PYTHONHASHSEED=0`` so its output is the same
bytes on every run (any order is equally correct; only the bytes would differ).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from ...symbolic.cache import module_name

#: Folder of the shipped sources (package data, not importable modules).
SHIPPED_DIR = Path(__file__).resolve().parent / "_shipped_kernels"


def shipped_source(name: str, key: str) -> str | None:
    """The shipped generated source of factor ``name`` with cache key ``key``, or ``None``."""
    path = SHIPPED_DIR / f"{module_name(name, key)}.py.txt"
    try:
        return path.read_text()
    except OSError:
        return None


def builtin_kernels() -> list[tuple]:
    """``(factor type, variable pattern)`` of every shipped built-in kernel."""
    from .generated import _LIE_TYPES, vector_factor_types
    from .reprojection import bal_reprojection

    out = []
    for between, prior in list(_LIE_TYPES.values()) + [vector_factor_types(2),
                                                         vector_factor_types(3)]:
        out.append((between, between._pattern(("a", "b"))))
        out.append((prior, prior._pattern(("x",))))
    out.append((bal_reprojection, bal_reprojection._pattern(["camera", "point"])))
    return out


def generate(folder: Path) -> list[Path]:
    """Derive every built-in kernel (SymPy) and write its source into ``folder``."""
    from ...symbolic.derive import derive_source

    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for ftype, pattern in builtin_kernels():
        key = ftype.cache_key(pattern)
        path = folder / f"{module_name(ftype.name, key)}.py.txt"
        path.write_text(derive_source(ftype, pattern))
        written.append(path)
    return written


def main(argv: list[str] | None = None) -> int:
    """Regenerate :data:`SHIPPED_DIR` (stale files are removed)."""
    argv = sys.argv[1:] if argv is None else argv
    if os.environ.get("PYTHONHASHSEED") != "0":  # deterministic order (module docstring)
        import subprocess

        env = dict(os.environ, PYTHONHASHSEED="0")
        return subprocess.call([sys.executable, "-m", __spec__.name, *argv], env=env)
    folder = Path(argv[0]) if argv else SHIPPED_DIR
    old = set(folder.glob("*.py.txt")) if folder.is_dir() else set()
    written = generate(folder)
    for stale in old - set(written):
        stale.unlink()
    for p in written:
        print(p)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
