"""Fuzz the g2o, TORO and BAL readers with mutated lines, plain and ``.gz`` / ``.bz2`` (hypothesis).

For every mutated file the reader must either raise an ``FgoptError`` or return exactly the
graph that a slow, line-by-line reference parser (``tests/io/_fuzz.py``, written from the format
description) builds: never another exception, never a hang (hypothesis' deadline), never a
silently different graph. A derandomized set runs here; ``benchmarks/fuzz_readers.py`` runs
10,000+ inputs per format.
"""

from __future__ import annotations

import gzip

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fgopt.errors import FgoptError, FileFormatError
from fgopt.io import read, read_bal, read_g2o

from ._fuzz import (BAL, POSE2, POSE3, TORO, TORO_COV, check_bal, check_compressed,
                    check_g2o, compressed, mutated, mutated_toro, reference_g2o)

@pytest.fixture(scope="module", autouse=True)
def _compiled_readers():
    """Read each base once first: numba compiles the scanner outside hypothesis' deadline."""
    check_g2o(POSE2), check_g2o(POSE3), check_bal(BAL)


FUZZ = settings(max_examples=150, deadline=3000, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow])


@FUZZ
@given(mutated(POSE2))
def test_fuzz_g2o_2d(text):
    check_g2o(text)


@FUZZ
@given(mutated(POSE3))
def test_fuzz_g2o_3d(text):
    check_g2o(text)


@FUZZ
@given(mutated_toro())
def test_fuzz_toro(text):
    """TORO (VERTEX2 / EDGE2 in TORO's information order or GTSAM's covariance layout, EQUIV)
    against the reference."""
    check_g2o(text)


@FUZZ
@given(mutated(BAL))
def test_fuzz_bal(text):
    check_bal(text)


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


@pytest.mark.parametrize("codec", ["gz", "bz2"])
def test_fuzz_compressed(codec, fuzz_dir):
    """Compressed g2o / TORO / BAL files, mutated and / or damaged after compression, read
    through ``fgopt.io.read`` (decompression, format detection, reader)."""

    @FUZZ
    @given(compressed(codec))
    def run(case):
        _name, fname, blob = case
        check_compressed(fuzz_dir / fname, codec, blob)

    run()


def test_damaged_deflate_stream_is_a_file_format_error(tmp_path):
    """A .gz file whose deflate data is damaged (zlib.error, not an OSError, from Python's gzip)
    is a FileFormatError naming the file (found by the fuzzer)."""
    blob = bytearray(gzip.compress(POSE2.encode(), mtime=0))
    blob[10] |= 0x06  # first deflate block: reserved block type 3
    path = tmp_path / "damaged.g2o.gz"
    path.write_bytes(bytes(blob))
    with pytest.raises(FileFormatError, match="damaged.g2o.gz: cannot read: .*invalid block"):
        read(path)


@settings(max_examples=100, deadline=3000, derandomize=True)
@given(st.binary(max_size=200))
def test_fuzz_random_bytes(data):
    for reader in (read_g2o, read_bal):
        try:
            reader("bytes.bin", data=data)
        except FgoptError:
            pass


@pytest.mark.parametrize("text", [POSE2, POSE3, TORO, TORO_COV])
def test_unmutated_bases_are_valid(text):
    assert reference_g2o(text) is not None
    assert check_g2o(text)


def test_unmutated_bal_is_valid():
    assert check_bal(BAL)
