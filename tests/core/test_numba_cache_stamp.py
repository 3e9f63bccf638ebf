"""numba's cache entries of fgopt's code are stamped with every fgopt module that holds numba
code, not only the function's own file (numba's rule), so a kernel compiled against an older
version of a kernel it calls in another file is recompiled, never loaded stale."""

from __future__ import annotations

import pytest

from fgopt import _cache_root


def _package(tmp_path, kernel: str, plain: str):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "kernels.py").write_text(kernel)
    (tmp_path / "plain.py").write_text(plain)
    return str(tmp_path)


def test_digest_follows_every_module_with_numba_code_and_no_other(tmp_path):
    """Editing a module with numba code changes the digest; editing one without does not."""
    kernel = "from fgopt._jit import njit\n@njit(cache=True)\ndef f(x):\n    return x\n"
    pkg = _package(tmp_path, kernel, "X = 1\n")
    before = _cache_root.numba_sources_digest(pkg)
    _cache_root._DIGESTS.clear()
    (tmp_path / "plain.py").write_text("X = 2\n")
    assert _cache_root.numba_sources_digest(pkg) == before
    _cache_root._DIGESTS.clear()
    (tmp_path / "sub" / "kernels.py").write_text(kernel.replace("return x", "return x + 1"))
    assert _cache_root.numba_sources_digest(pkg) != before
    _cache_root._DIGESTS.clear()


def test_fgopt_kernels_cache_under_the_root_stamped_with_the_package_digest():
    """An fgopt kernel's numba cache (given to its dispatcher when it is built, numba's own
    locator list untouched) lives under ``<root>/numba`` and stamps each entry with its own
    file's hash and the package's numba-sources digest."""
    pytest.importorskip("numba")
    from numba.core import caching

    from fgopt.manifolds._kernels import dispatch

    locators = list(caching.CacheImpl._locator_classes)
    impl = dispatch.batch_retract.dispatcher._cache._impl
    assert caching.CacheImpl._locator_classes == locators
    loc = impl.locator
    assert loc.get_cache_path().startswith(str(_cache_root.root() / _cache_root.NUMBA))
    own, digest = loc.get_source_stamp()
    assert digest == _cache_root.numba_sources_digest()
    assert isinstance(own, bytes) and len(own) == 32
