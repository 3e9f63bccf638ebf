"""The kernel cache runs only what fgopt wrote: entries are verified before import, broken ones
are regenerated with one warning, and the cache root is private."""

from __future__ import annotations

import importlib.util
import marshal
import os
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest

import fgopt
from fgopt import _cache_root
from fgopt.cli import main
from fgopt.errors import FgoptError
from fgopt.symbolic import V2, cache
from fgopt.symbolic.cache import CacheWarning

X = np.array([[1.0, 2.0], [-0.5, 0.25], [3.0, -1.5]])
M = np.array([[0.5, 0.5], [0.0, 1.0], [-2.0, 0.125]])


def trust_scaled(x: V2, m: V2) -> V2:
    return V2(x[0] * 3.25 + x[1], x[1] * x[1]) - m


def expected_residual() -> np.ndarray:
    return np.stack([X[:, 0] * 3.25 + X[:, 1], X[:, 1] ** 2], axis=1) - M


def fresh_kernel():
    """A new factor type of ``trust_scaled`` (nothing memoized): its kernel comes from disk."""
    ft = fgopt.factor(trust_scaled)
    return ft, ft.kernel(("x",))


@pytest.fixture
def entry():
    """The cache entry of ``trust_scaled`` (written if missing), not imported in this process:
    ``(path, bytes fgopt wrote)``."""
    ft, _ = fresh_kernel()
    module = ft.generated_module(("x",))
    path = Path(module.__file__)
    sys.modules.pop(module.__name__)
    yield path, path.read_bytes()
    sys.modules.pop(path.stem, None)


def reload_expecting_one_warning(path: Path, regenerated: bool = True):
    """Build the kernel again; exactly one CacheWarning names the entry, which was regenerated
    (derived again). Returns the kernel."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        derived = cache.STATS["derived"]
        _, kernel = fresh_kernel()
    ours = [w for w in caught if issubclass(w.category, CacheWarning)]
    assert len(ours) == 1, [str(w.message) for w in caught]
    assert path.stem in str(ours[0].message)
    assert cache.STATS["derived"] == derived + regenerated
    return kernel


def assert_right(kernel, path: Path, original: bytes) -> None:
    np.testing.assert_allclose(kernel.residual((X,), M), expected_residual(), rtol=0, atol=1e-14)
    res, jac = kernel.linearize((X,), M)
    np.testing.assert_allclose(jac[:, 0, 0], 3.25)
    assert path.read_bytes() == original  # the entry was rewritten as fgopt made it
    assert cache.verify(path) is None


def test_planted_statement_never_runs(entry, tmp_path):
    """A statement added to a cached module is never executed (its marker file is not
    created); the entry is regenerated with one warning and results stay right."""
    path, original = entry
    marker = tmp_path / "planted-ran"
    path.write_bytes(original + f"\nopen({str(marker)!r}, 'w').write('x')\n".encode())
    kernel = reload_expecting_one_warning(path)
    assert not marker.exists()
    assert_right(kernel, path, original)


def test_planted_python_bytecode_never_runs(entry, tmp_path):
    """A ``.pyc`` planted in the kernels' ``__pycache__`` (with the header Python's import would
    accept for the source) never runs: fgopt does not use Python's bytecode cache."""
    path, original = entry
    marker = tmp_path / "pyc-ran"
    pyc = Path(importlib.util.cache_from_source(str(path)))
    pyc.parent.mkdir(exist_ok=True)
    st = path.stat()
    header = (importlib.util.MAGIC_NUMBER + b"\0\0\0\0" + int(st.st_mtime).to_bytes(4, "little")
              + (st.st_size & 0xFFFFFFFF).to_bytes(4, "little"))
    code = compile(f"open({str(marker)!r}, 'w').write('x')\n" + original.decode(), str(path),
                   "exec")
    pyc.write_bytes(header + marshal.dumps(code))
    try:
        _, kernel = fresh_kernel()
        assert not marker.exists()
        assert_right(kernel, path, original)
    finally:
        pyc.unlink()


def test_edited_constant_is_detected(entry):
    """An edited constant in a cached module (3.25 -> 4.25) does not change residuals: the
    edit is detected and the entry regenerated."""
    path, original = entry
    assert original.count(b"3.25") >= 2
    path.write_bytes(original.replace(b"3.25", b"4.25"))
    assert "differ" in cache.verify(path)
    assert_right(reload_expecting_one_warning(path), path, original)


@pytest.mark.parametrize("damage", ["truncated", "empty", "syntax", "unsigned"])
def test_damaged_entry_is_regenerated(entry, damage):
    """A truncated, empty, syntactically broken or unsigned entry is discarded and regenerated
    with one warning (no SyntaxError / AttributeError reaches the user)."""
    path, original = entry
    if damage == "truncated":
        path.write_bytes(original[: len(original) // 2])
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "syntax":
        path.write_bytes(original.replace(b"def residual(", b"def residual(("))
    else:
        path.with_name(path.stem + ".sig").unlink()
    assert_right(reload_expecting_one_warning(path), path, original)


@pytest.mark.parametrize("content", [b"def broken(:\n", b"X = 1\n"])
def test_signed_entry_that_does_not_import_is_regenerated(entry, content):
    """Even a correctly signed entry that fails to import (SyntaxError) or lacks the kernels its
    factor needs (would be an AttributeError) is regenerated with one warning."""
    path, original = entry
    path.write_bytes(content)
    path.with_name(path.stem + ".sig").write_text(cache._sign(path.stem, content))
    assert cache.verify(path) is None
    assert_right(reload_expecting_one_warning(path), path, original)


def test_tampered_bytecode_is_not_run(entry, tmp_path):
    """fgopt's own compiled-code file beside an entry is signed too: a replaced body never runs
    (one warning; recompiled from the verified source, which need not be derived again)."""
    path, original = entry
    bc = path.with_name(path.stem + cache._BC)
    assert bc.exists()
    marker = tmp_path / "bc-ran"
    code = compile(f"open({str(marker)!r}, 'w').write('x')\n", str(path), "exec")
    blob = bc.read_bytes()
    bc.write_bytes(blob[:64] + marshal.dumps(code))  # the real header, another body
    assert_right(reload_expecting_one_warning(path, regenerated=False), path, original)
    assert not marker.exists()


def test_signature_is_bound_to_the_entry_name(tmp_path, monkeypatch):
    """A signature copied from another entry with the same bytes does not verify."""
    monkeypatch.setenv("FGOPT_CACHE_DIR", str(tmp_path / "root"))
    cache.store("trust_a", "k1", "VALUE = 1\n")
    cache.store("trust_b", "k1", "VALUE = 1\n")
    a = cache.module_path("trust_a", "k1")
    b = cache.module_path("trust_b", "k1")
    b.with_name(b.stem + ".sig").write_bytes(a.with_name(a.stem + ".sig").read_bytes())
    assert cache.verify(a) is None and "differ" in cache.verify(b)


def test_a_key_from_another_root_does_not_verify(tmp_path, monkeypatch):
    """Entries signed under one root's key do not verify under another root's key (copying a
    cache folder's entries without its key gives nothing that runs)."""
    monkeypatch.setenv("FGOPT_CACHE_DIR", str(tmp_path / "one"))
    cache.store("trust_c", "k1", "VALUE = 2\n")
    src = cache.module_path("trust_c", "k1")
    monkeypatch.setenv("FGOPT_CACHE_DIR", str(tmp_path / "two"))
    dst = cache.module_path("trust_c", "k1")
    _cache_root.secret_key()
    for p in src.parent.glob(src.stem + ".*"):
        (dst.parent / p.name).write_bytes(p.read_bytes())
    assert "differ" in cache.verify(dst)
    assert _cache_root.secret_key(tmp_path / "one") != _cache_root.secret_key(tmp_path / "two")


# --------------------------------------------------------------------------------- the root
def test_root_is_created_private(tmp_path, monkeypatch):
    """A new root and its folders are 0700, the signing key 0600."""
    monkeypatch.setenv("FGOPT_CACHE_DIR", str(tmp_path / "a" / "root"))
    root = _cache_root.root()
    cache.store("trust_d", "k1", "VALUE = 3\n")
    for d in (root, root / "kernels"):
        assert d.stat().st_mode & 0o777 == 0o700, d
    assert (root / "key").stat().st_mode & 0o777 == 0o600


@pytest.mark.parametrize("mode", [0o777, 0o770, 0o720])
def test_root_writable_by_others_is_refused(tmp_path, monkeypatch, mode):
    """A root writable by group or others is refused with an FgoptError naming it and saying
    what to do."""
    root = tmp_path / "shared"
    root.mkdir()
    root.chmod(mode)
    monkeypatch.setenv("FGOPT_CACHE_DIR", str(root))
    with pytest.raises(FgoptError, match=r"(?s)shared.*writable by group or others.*chmod 700"):
        cache.cache_dir()


def test_root_owned_by_another_user_is_refused(tmp_path, monkeypatch):
    """A root owned by another user is refused (ownership simulated: this process claims
    another uid, as tests may run as root)."""
    root = tmp_path / "theirs"
    root.mkdir(mode=0o700)
    monkeypatch.setenv("FGOPT_CACHE_DIR", str(root))
    monkeypatch.setattr(os, "getuid", lambda: root.stat().st_uid + 1)
    with pytest.raises(FgoptError, match=r"(?s)theirs.*is owned by uid.*not by you.*"
                                         "FGOPT_CACHE_DIR"):
        cache.module_path("trust_e", "k1")


@pytest.mark.parametrize("problem", ["foreign", "world-writable"])
def test_fallback_under_temp_is_checked(tmp_path, monkeypatch, problem):
    """When the preferred root cannot be created, the fallback ``<temp>/fgopt-<uid>`` is
    checked like any root: one made by someone else (or writable by all) is refused."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("FGOPT_CACHE_DIR", str(blocker / "cache"))  # under a file: OSError
    temp = tmp_path / "temp"
    temp.mkdir()
    monkeypatch.setattr("tempfile.tempdir", str(temp))
    uid = os.getuid()
    planted = temp / f"fgopt-{uid}"
    planted.mkdir(mode=0o700)
    if problem == "foreign":
        monkeypatch.setattr(os, "getuid", lambda: uid + 1)
        planted.rename(temp / f"fgopt-{uid + 1}")
        planted = temp / f"fgopt-{uid + 1}"
    else:
        planted.chmod(0o777)
    with pytest.raises(FgoptError, match=str(planted)):
        cache.cache_dir()


def test_fallback_under_temp_is_created_private(tmp_path, monkeypatch):
    """The temp fallback is made 0700 when it does not exist yet."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("FGOPT_CACHE_DIR", str(blocker / "cache"))
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path))
    assert cache.cache_dir() == tmp_path / f"fgopt-{os.getuid()}" / "kernels"
    assert (tmp_path / f"fgopt-{os.getuid()}").stat().st_mode & 0o777 == 0o700


def test_key_readable_by_others_is_refused(tmp_path, monkeypatch):
    """A signing key others can read could forge signatures: refused."""
    monkeypatch.setenv("FGOPT_CACHE_DIR", str(tmp_path / "root"))
    key = _cache_root.root() / "key"
    key.write_bytes(os.urandom(32))
    key.chmod(0o644)
    with pytest.raises(FgoptError, match="mode 0600"):
        _cache_root.secret_key()


def test_numba_cache_of_fgopt_lives_under_the_root(tmp_path):
    """numba's cache for fgopt's own functions and for generated kernels is under
    ``<root>/numba`` whether numba is imported before or after fgopt; a user's own numba
    function keeps numba's usual place."""
    user = tmp_path / "user_mod.py"
    user.write_text("import numba\n@numba.njit(cache=True)\ndef f(x):\n    return x + 1\n")
    for numba_first in (False, True):
        root = tmp_path / f"root{int(numba_first)}"
        code = textwrap.dedent(f"""
            import sys
            {'import numba' if numba_first else ''}
            import fgopt
            from fgopt.symbolic import cache
            from fgopt.manifolds._kernels import se2
            sys.path.insert(0, {str(tmp_path)!r})
            import user_mod
            mod = cache.store("trust_numba", "k1",
                              "import numba\\n@numba.njit(cache=True)\\ndef g(x):\\n    return x\\n")
            print(se2.se2_compose._cache._cache_path)
            print(mod.g._cache._cache_path)
            print(user_mod.f._cache._cache_path)
        """)
        env = {**os.environ, "FGOPT_CACHE_DIR": str(root)}
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             env=env, timeout=300, check=False)
        assert out.returncode == 0, out.stderr[-3000:]
        package, kernel, users = out.stdout.split()
        assert Path(package).parent == root / "numba"
        assert Path(kernel).parent == root / "numba"
        assert not Path(users).is_relative_to(root)


# ------------------------------------------------------------------------------ command line
def test_cli_cache_info_and_clear(tmp_path, monkeypatch, capsys):
    """``fgopt cache info`` shows the root, entries, sizes and which entries fail verification;
    ``fgopt cache clear`` removes them."""
    monkeypatch.setenv("FGOPT_CACHE_DIR", str(tmp_path / "root"))
    cache.store("trust_f", "k1", "VALUE = 1\n")
    cache.store("trust_g", "k1", "VALUE = 2\n")
    cache.module_path("trust_g", "k1").write_text("VALUE = 3\n")
    assert main(["cache", "info"]) == 0
    out = capsys.readouterr().out
    assert str(tmp_path / "root") in out and "0700" in out
    assert "2 entries" in out and "1 verified" in out and "1 failed" in out
    assert "fgk_trust_g_k1" in out and "differ" in out
    assert main(["cache", "clear"]) == 0
    assert "removed 2 kernel entries" in capsys.readouterr().out
    assert list((tmp_path / "root" / "kernels").glob("fgk_*")) == []
    assert main(["cache", "info"]) == 0
    assert "0 entries" in capsys.readouterr().out


def test_cli_cache_refuses_an_unsafe_root(tmp_path, monkeypatch, capsys):
    """``fgopt cache clear`` on a root others can write exits 2 with the reason; nothing is
    deleted."""
    root = tmp_path / "root"
    monkeypatch.setenv("FGOPT_CACHE_DIR", str(root))
    cache.store("trust_h", "k1", "VALUE = 1\n")
    root.chmod(0o777)
    assert main(["cache", "clear"]) == 2
    assert "writable by group or others" in capsys.readouterr().err
    assert (root / "kernels" / "fgk_trust_h_k1.py").exists()
