"""Build and load the fast solvers' compiled kernel (``admm_kernel.c``, its interface in
``admm_kernel.h``): the ADMM element loop,
the AMG-preconditioned conjugate gradients of the ADMM x-step and of the Mass Tensor method, and
the Mass Tensor method's tensor sums.

Compiled once per source version with cffi and the C compiler that dolfinx's own JIT uses (the
Makefile installs gcc and python3-dev for it), into a per-user cache directory
(``$XDG_CACHE_HOME/tissue-reference``, default ``~/.cache/tissue-reference``; override with
``TISSUE_KERNEL_CACHE``). The build goes to a temporary directory and is moved into place with
one rename, so concurrent processes (pytest workers, MPI ranks) never load a half-written file.

``load()`` returns ``(ffi, lib)`` or None when no compiler is usable, after one warning; the
solvers then run their numpy forms (same arithmetic). ``TISSUE_NO_CKERNEL=1`` forces numpy.
"""
from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.util
import os
import sys
import sysconfig
import tempfile
import warnings
from pathlib import Path

from tissue_reference.meshes.io import user_cache_root

SOURCE = Path(__file__).with_name("admm_kernel.c")
HEADER = Path(__file__).with_name("admm_kernel.h")
# -march=native: the element update vectorizes over elements (the build is keyed by this CPU's
# model and flags, so a cache shared by different machines never loads a foreign build);
# no -ffast-math: NaN/inf must propagate to the divergence checks.
CFLAGS = ["-O3", "-march=native", "-fno-math-errno"]

_loaded: dict = {}


def _cache_dir() -> Path:
    root = os.environ.get("TISSUE_KERNEL_CACHE")
    return Path(root) if root else user_cache_root()


def _cpu() -> str:
    """This CPU's model name and feature flags (Linux), for the build key."""
    try:
        with open("/proc/cpuinfo") as fh:
            return "".join(sorted({ln for ln in fh if ln.startswith(("model name", "flags"))}))
    except OSError:
        import platform
        return platform.processor()


def _module_name(src: str, cdef: str) -> str:
    key = "\0".join([src, cdef, " ".join(CFLAGS), sys.version, sysconfig.get_platform(), _cpu()])
    return "_tissue_admm_" + hashlib.sha256(key.encode()).hexdigest()[:16]


def _build(name: str, src: str, cdef: str, target_dir: Path) -> Path:
    import cffi

    ffi = cffi.FFI()
    ffi.cdef(cdef)   # the interface: admm_kernel.h, which the source includes
    ffi.set_source(name, src, extra_compile_args=CFLAGS, libraries=["m"],
                   include_dirs=[str(HEADER.parent)])
    target_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target_dir, prefix=".build-") as tmp:
        built = Path(ffi.compile(tmpdir=tmp, verbose=False))
        final = target_dir / built.name
        os.replace(built, final)  # atomic: other processes see the whole file or none
    return final


def _import(name: str, path: Path):
    loader = importlib.machinery.ExtensionFileLoader(name, str(path))
    spec = importlib.util.spec_from_file_location(name, str(path), loader=loader)
    mod = importlib.util.module_from_spec(spec)
    loader.exec_module(mod)
    return mod


def load():
    """(ffi, lib) of the compiled kernel, or None (numpy fallback; warned once)."""
    if "lib" in _loaded:
        return _loaded["lib"]
    result = None
    if os.environ.get("TISSUE_NO_CKERNEL", "") not in ("", "0"):
        _loaded["lib"] = None
        return None
    try:
        src = SOURCE.read_text()
        cdef = HEADER.read_text()
        name = _module_name(src, cdef)
        d = _cache_dir()
        suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
        path = d / (name + suffix)
        if not path.exists():
            try:
                path = _build(name, src, cdef, d)
            except OSError:  # cache directory not writable: a per-user temporary one
                d = Path(tempfile.gettempdir()) / f"tissue-reference-{os.getuid()}"
                path = d / (name + suffix)
                if not path.exists():
                    path = _build(name, src, cdef, d)
        mod = _import(name, path)
        result = (mod.ffi, mod.lib)
    except Exception as exc:  # noqa: BLE001  (no compiler, no headers, read-only cache: numpy)
        warnings.warn(f"fast solvers: compiled kernel unavailable ({type(exc).__name__}: "
                      f"{exc}); using their numpy forms (same results, slower). Set "
                      f"TISSUE_KERNEL_CACHE to a writable directory or install gcc and "
                      f"python3-dev.", RuntimeWarning, stacklevel=3)
    _loaded["lib"] = result
    return result
