"""Pose graphs beyond the shared data folder: where they come from, and how to get them.

    python -m benchmarks.extra_data [--dir DIR] [--check]

The shared folder (``$FGOPT_DATA``) holds one file of each kind; the final-cost target of
issue 12 is about "every graph of the same kinds", so the benchmarks also run on the public
pose graphs below. They are not copied into the repository: this script downloads each file
from a pinned commit of its public repository (raw.githubusercontent.com), checks its git blob
SHA-1, and converts TORO ``VERTEX2``/``EDGE2`` files to g2o ``VERTEX_SE2``/``EDGE_SE2`` (the
information reordered from TORO's ``xx xy yy tt xt yt`` to g2o's ``xx xy xt yy yt tt``, i.e.
read exactly as ``fgopt.io.read`` reads the TORO file), so that every peer's g2o reader
(``gtsam.readG2o``, the C++ Ceres program, ``benchmarks.problems.read_g2o``) reads the same
problem. Files land in ``$FGOPT_EXTRA_DATA`` (default ``~/.cache/fgopt/extra-data``);
``--check`` only verifies what is there.

* M3500a/b/c (Carlone's M3500 with extra rotation noise; AndreaCensi/efpno): the "M3500 variants
  with extra rotation noise" of issue 12.
* sphere_bignoise_vertex3 (SE-Sync's data folder): the issue's "large-noise sphere".
* MIT, city10000, ais2klinik (SE-Sync's data folder): more 2D graphs with an initial guess.
* CSAIL, kitti_00, kitti_05 (SE-Sync's data folder): edges only (the reader chains odometry).
* problem-21-11315-pre.txt (Trafalgar-21 of Agarwal et al.'s BAL collection, from apex-solver's
  data folder): a second real BAL problem of Ladybug-49's size for ``benchmarks/ba.py``.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import urllib.request
from dataclasses import dataclass
from pathlib import Path

_SESYNC = ("david-m-rosen/SE-Sync", "9b631b6b82d8aa7d32ab846412ae1c070412b7b6")
_EFPNO = ("AndreaCensi/efpno", "b2dc56c8c4b9d41f38b7052be9d3e5f2669ce178")
_APEX = ("amin-abouee/apex-solver", "48e1f09c35c568ffbe7ac4a7d19b8d7995df20f4")


@dataclass(frozen=True)
class ExtraFile:
    name: str        # file name under the extra-data folder (after conversion)
    repo: str
    commit: str
    path: str        # path in the repository
    blob: str        # git blob SHA-1 of the original file
    toro: bool = False  # convert TORO VERTEX2/EDGE2 to g2o


FILES = [
    ExtraFile("M3500a.g2o", *_EFPNO, "data/M3500a.g2o", "269b7d51bca483b963075f6eb1151320ed7b5fb9",
              toro=True),
    ExtraFile("M3500b.g2o", *_EFPNO, "data/M3500b.g2o", "21d4f410448f092466196e433705f6a96463e0a1",
              toro=True),
    ExtraFile("M3500c.g2o", *_EFPNO, "data/M3500c.g2o", "1c0164711eb5c9fce86dbb4bbf4010f7d1ad987f",
              toro=True),
    ExtraFile("sphere_bignoise_vertex3.g2o", *_SESYNC, "data/sphere_bignoise_vertex3.g2o",
              "c09e6f4c0f978664f3a090dfac9683d9d50e28e1"),
    ExtraFile("MIT.g2o", *_SESYNC, "data/MIT.g2o", "2c329e3373315abc5b20aa0bebd65fa2d33b3f98"),
    ExtraFile("city10000.g2o", *_SESYNC, "data/city10000.g2o",
              "cd8bc910725bbde593f28ed76551e8fe086ff971"),
    ExtraFile("ais2klinik.g2o", *_SESYNC, "data/ais2klinik.g2o",
              "a54c0ceb46459570578523c281f261d8116f12fc"),
    ExtraFile("CSAIL.g2o", *_SESYNC, "data/CSAIL.g2o", "986c39e0808a788241c8ed7c2e41d7621e9cf130"),
    ExtraFile("kitti_00.g2o", *_SESYNC, "data/kitti_00.g2o",
              "e4863573ca2b87bcd1a1710694eab2d871bcf656"),
    ExtraFile("kitti_05.g2o", *_SESYNC, "data/kitti_05.g2o",
              "636ca29f0cc5fb7dba379d11e3e35b7040c465cc"),
    ExtraFile("problem-21-11315-pre.txt", *_APEX, "data/bundle_adjustment/problem-21-11315-pre.txt",
              "4fc68d1b9aca5ac13b4ee241677469a5e38cc7e1"),
]
BY_NAME = {f.name: f for f in FILES}


def extra_dir() -> Path:
    """``$FGOPT_EXTRA_DATA``, else ``~/.cache/fgopt/extra-data``."""
    env = os.environ.get("FGOPT_EXTRA_DATA")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "fgopt" / "extra-data"


def git_blob_sha1(data: bytes) -> str:
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


def toro_to_g2o(text: str) -> str:
    """TORO ``VERTEX2``/``EDGE2`` lines -> g2o ``VERTEX_SE2``/``EDGE_SE2`` (other lines kept).

    TORO's information is ``xx xy yy tt xt yt``; g2o's upper triangle of (x, y, theta) is
    ``xx xy xt yy yt tt``.
    """
    out = []
    for line in text.splitlines():
        t = line.split()
        if t and t[0] == "VERTEX2":
            out.append(" ".join(["VERTEX_SE2"] + t[1:]))
        elif t and t[0] == "EDGE2":
            xx, xy, yy, tt, xt, yt = t[6:12]
            out.append(" ".join(["EDGE_SE2"] + t[1:6] + [xx, xy, xt, yy, yt, tt]))
        else:
            out.append(line)
    return "\n".join(out) + "\n"


def ensure(name: str, download: bool = True) -> Path:
    """Path of the extra file ``name``, downloading (and converting) it if missing."""
    f = BY_NAME[name]
    path = extra_dir() / f.name
    if path.exists():
        return path
    if not download:
        raise FileNotFoundError(f"{path} missing: run python -m benchmarks.extra_data")
    url = f"https://raw.githubusercontent.com/{f.repo}/{f.commit}/{f.path}"
    with urllib.request.urlopen(url, timeout=60) as r:
        data = r.read()
    sha = git_blob_sha1(data)
    if sha != f.blob:
        raise ValueError(f"{url}: blob SHA-1 {sha}, expected {f.blob}")
    path.parent.mkdir(parents=True, exist_ok=True)
    text = data.decode()
    tmp = path.with_suffix(".tmp")
    tmp.write_text(toro_to_g2o(text) if f.toro else text)
    os.replace(tmp, path)
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", default=None, help="target folder (sets FGOPT_EXTRA_DATA)")
    ap.add_argument("--check", action="store_true", help="only report what is present")
    args = ap.parse_args(argv)
    if args.dir:
        os.environ["FGOPT_EXTRA_DATA"] = args.dir
    missing = 0
    for f in FILES:
        try:
            p = ensure(f.name, download=not args.check)
            print(f"ok       {p}")
        except (OSError, ValueError) as exc:
            missing += 1
            print(f"missing  {f.name}: {exc}")
    return 1 if missing else 0


if __name__ == "__main__":
    sys.exit(main())
