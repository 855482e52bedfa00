"""Fixtures shared by the test modules."""
import math
import sys

import pytest
from case_texts import COARSE

from tissue_reference.errors import CaseError
from tissue_reference.meshes import builders


@pytest.fixture(scope="session", autouse=True)
def _mesh_cache(tmp_path_factory):
    """The builtin meshes are cached for this session only (meshes.mesh_cache), so no test
    depends on what an earlier run left in the user's cache; subprocesses inherit it."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TISSUE_MESH_CACHE", str(tmp_path_factory.mktemp("mesh_cache")))
        yield


@pytest.fixture(scope="module")
def coarse_builders():
    """Builtin meshes built once at a coarse size, whatever size the case asks for."""
    cache = {}

    def cached(name, real):
        def build(size, *, out=None):
            if not (size > 0 and math.isfinite(size)):
                raise CaseError(f"mesh size must be a positive length in mm, got {size!r}")
            if name not in cache:
                cache[name] = real(COARSE.get(name, 6.0))
            return cache[name]
        return build

    with pytest.MonkeyPatch.context() as mp:
        for name, real in list(builders.BUILDERS.items()):
            mp.setitem(builders.BUILDERS, name, cached(name, real))
        yield cache


@pytest.fixture(scope="module", autouse=True)
def _forget_kept_solvers():
    """The reference solvers a test module kept for reuse are forgotten when it ends, which
    frees their matrices and factors: the one test process would otherwise carry every
    module's."""
    yield
    kept = sys.modules.get("tissue_reference.fem_reference.kept")
    if kept is not None:
        kept.forget_solvers()
