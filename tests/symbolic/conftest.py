"""Symbolic tests share one kernel cache under .pytest_cache (warm on reruns, away from ~)."""

from __future__ import annotations

import os

import pytest


@pytest.fixture(scope="session", autouse=True)
def _kernel_cache_dir(request):
    if "FGOPT_CACHE_DIR" not in os.environ:
        os.environ["FGOPT_CACHE_DIR"] = str(request.config.cache.mkdir("fgopt-kernels"))
    yield
