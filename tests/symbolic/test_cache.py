"""The on-disk kernel cache: a second process neither re-derives nor re-compiles."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

SCRIPT = textwrap.dedent('''
    import json, sys, time
    import numpy as np
    import fgopt
    from fgopt.symbolic import V2, Pose2, atan2, cache, runtime
    runtime.NUMPY_MAX_BATCH = 0  # run the numba kernels (small batches use their NumPy twins)

    @fgopt.factor
    def landmark_obs(pose: Pose2, landmark: V2, measured: V2) -> V2:
        d = pose.inverse() * landmark
        return V2(d.norm(), atan2(d[1], d[0])) - measured

    t = time.perf_counter()
    f = landmark_obs(fgopt.key("x", 0), fgopt.key("l", 0), np.array([1.0, 0.1]))
    args = (np.array([[1.0, 0.0, 0.5, 0.2]]), np.array([[3.0, 1.0]]))
    res, jac = f.kernel.linearize(args, np.array([[1.0, 0.1]]))
    res2 = f.kernel.residual(args, np.array([[1.0, 0.1]]))
    load = time.perf_counter() - t
    mod = sys.modules[f.kernel.linearize.__module__]
    stats = [mod._linearize_kernel.stats, mod._residual_kernel.stats]
    print(json.dumps({
        "stats": cache.STATS, "sympy": "sympy" in sys.modules, "load": load,
        "hits": sum(sum(s.cache_hits.values()) for s in stats),
        "misses": sum(sum(s.cache_misses.values()) for s in stats),
        "res": res.tolist(), "jac": jac.tolist(), "file": mod.__file__}))
''')


def _run(tmp_path: Path) -> dict:
    script = tmp_path / "user_factor.py"
    script.write_text(SCRIPT)
    env = {**os.environ, "FGOPT_CACHE_DIR": str(tmp_path / "cache"),
           "PYTHONPATH": str(Path(__file__).resolve().parents[2])}  # this checkout's fgopt
    out = subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True,
                         timeout=600, cwd=tmp_path, check=False)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_second_process_loads_without_deriving_or_compiling(tmp_path):
    first = _run(tmp_path)
    assert first["stats"]["derived"] == 1 and first["misses"] == 2
    second = _run(tmp_path)
    assert second["stats"] == {"derived": 0, "loaded": 1, "written": 0, "shipped": 0}
    assert second["sympy"] is False  # nothing symbolic ran
    assert second["misses"] == 0 and second["hits"] == 2  # numba loaded both kernels from disk
    assert second["res"] == first["res"] and second["jac"] == first["jac"]
    assert second["file"] == first["file"]
    assert Path(first["file"]).parent == tmp_path / "cache" / "kernels"


def test_editing_the_function_changes_the_key(tmp_path):
    from fgopt.symbolic import V2, cache

    def make(scale):
        def f(x: V2) -> V2:
            return x * scale

        return f

    def g(x: V2) -> V2:
        return x * 2

    def h(x: V2) -> V2:
        return x * 3

    key_g = cache.kernel_key(g, ("g",))
    assert key_g == cache.kernel_key(g, ("g",))
    assert key_g != cache.kernel_key(h, ("g",))  # different source
    assert cache.kernel_key(make(2), ("f",)) != cache.kernel_key(make(3), ("f",))  # closure value


_EDITED = '''
import functools


def helper(x):
    return x + 1


@functools.lru_cache(maxsize=None)
def decorated(x):
    return (x +
            {body})
    # a trailing comment


def nested(x):
    def inner(y):
        return y * {body}

    class Local:
        value = 1

    return inner(x)


square = lambda x: x * x  # noqa: E731
'''


def _module_from(tmp_path: Path, name: str, source: str):
    import importlib.util

    path = tmp_path / f"{name}.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_function_source_is_getsource_up_to_trailing_comments(tmp_path):
    """function_source (the fingerprint's text, without inspect's tokenize pass) equals
    inspect.getsource for every function of fgopt's own modules whose source ends in code, and
    for decorated, nested and lambda definitions; after the last statement it leaves out only
    comments (inspect keeps indented ones)."""
    import importlib
    import inspect
    import types

    from fgopt.symbolic import cache

    module = _module_from(tmp_path, "edited_a", _EDITED.format(body="2"))
    for fn in (module.helper, module.nested, module.square):
        assert cache.function_source(fn) == inspect.getsource(fn)
    full = inspect.getsource(module.decorated.__wrapped__)
    assert full.startswith("@functools.lru_cache") and full.endswith("# a trailing comment\n")
    assert cache.function_source(module.decorated.__wrapped__) == full[:full.index("    #")]
    compared = 0
    for name in ("fgopt.io.g2o", "fgopt.solvers.lm", "fgopt.problem", "fgopt.symbolic.lie",
                 "fgopt.symbolic.pose", "fgopt.factors.library.generated", "fgopt.cli"):
        mod = importlib.import_module(name)
        members = [v for v in vars(mod).values() if getattr(v, "__module__", None) == name]
        members += [w for v in members if isinstance(v, type) for w in vars(v).values()]
        for fn in members:
            if isinstance(fn, types.FunctionType):
                try:
                    text = inspect.getsource(fn)
                except OSError:  # made by exec (dataclass methods): neither has a source
                    with pytest.raises(OSError):
                        cache.function_source(fn)
                    continue
                if text.rstrip().splitlines()[-1].lstrip().startswith("#"):
                    continue
                assert cache.function_source(fn) == text, fn.__qualname__
                compared += 1
    assert compared > 100


def test_fingerprint_follows_code_not_trailing_comments(tmp_path):
    """Editing a function's last (multi-line) expression or a nested function's body changes
    its fingerprint; editing a comment after its last statement does not."""
    from fgopt.symbolic import cache

    a = _module_from(tmp_path, "edited_b", _EDITED.format(body="2"))
    b = _module_from(tmp_path, "edited_c", _EDITED.format(body="3"))
    c = _module_from(tmp_path, "edited_d", _EDITED.format(body="2").replace(
        "# a trailing comment", "# another comment"))
    fp = cache.function_fingerprint
    assert fp(a.decorated.__wrapped__) != fp(b.decorated.__wrapped__)
    assert fp(a.nested) != fp(b.nested)
    assert fp(a.decorated.__wrapped__) == fp(c.decorated.__wrapped__)
    assert fp(a.helper) == fp(b.helper)
