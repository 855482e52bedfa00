"""Output files written whole or not at all, and output paths checked before any work starts.

Every output of the toolkit is written to a temporary file in the target folder and renamed
(``atomic_path``), so a file is written whole or not at all, and no temporary is left behind
after an error or an interrupt. ``check_output_file`` / ``check_output_dir`` refuse a path that
cannot be written before any work starts; ``user_cache_root`` is where kernels and meshes are
kept between runs.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

from tissue_reference.errors import WriteError

__all__ = ["atomic_path", "check_output_dir", "check_output_file", "save_figure",
           "user_cache_root"]


def os_reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


def user_cache_root() -> Path:
    """The toolkit's folder in the user's cache (``$XDG_CACHE_HOME/tissue-reference``, else
    ``~/.cache/tissue-reference``): compiled kernels and built meshes are kept below it."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "tissue-reference"


class atomic_path:
    """Context manager yielding a temporary path beside ``path``, renamed onto it on success.

    The temporary is removed whatever ends the block (an error, KeyboardInterrupt, a failed
    rename); a failure to write raises WriteError naming ``path``."""

    def __init__(self, path, suffix=None):
        self.path = Path(path)
        self.suffix = suffix if suffix is not None else self.path.suffix
        self.tmp = None

    def __enter__(self):
        if self.path.is_dir():
            raise WriteError(f"cannot write {str(self.path)!r}: it is a directory, expected a "
                             "file path")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=self.suffix,
                                       dir=self.path.parent)
        except OSError as exc:
            raise WriteError(f"cannot write {str(self.path)!r}: {os_reason(exc)}") from None
        try:
            os.close(fd)
        finally:
            self.tmp = Path(tmp)
        return self.tmp

    def _discard(self):
        if self.tmp is not None:
            try:
                self.tmp.unlink(missing_ok=True)
            except OSError:
                pass

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None:
            self._discard()
            return False
        try:
            # mkstemp makes the file 0600; give it the mode a plain open() would (umask applied)
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(self.tmp, 0o666 & ~umask)
            os.replace(self.tmp, self.path)
        except OSError as err:
            self._discard()
            raise WriteError(f"cannot write {str(self.path)!r}: {os_reason(err)}") from None
        except BaseException:
            self._discard()
            raise
        return False


def save_figure(fig, path, *, dpi: int = 100) -> Path:
    """Write a matplotlib figure as a PNG at ``path``, whole or not at all (``atomic_path``), and
    close it; returns the path."""
    import matplotlib.pyplot as plt

    path = Path(path)
    try:
        with atomic_path(path, suffix=".png") as tmp:
            fig.savefig(tmp, format="png", dpi=dpi)
    finally:
        plt.close(fig)
    return path


def _parent_folder(path: Path, what: str) -> Path:
    """The folder ``path`` goes into, made (with its missing parents) when it does not exist
    yet; WriteError when it, or the nearest of its parents that exists, is not a writable
    folder."""
    p = path.parent
    top = p
    while not top.exists() and top != top.parent:
        top = top.parent
    if not top.is_dir():
        raise WriteError(f"{what} {str(path)!r}: {str(top)!r} is not a folder")
    if top != p:
        _check_writable(top, path, what)
        try:
            p.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise WriteError(f"{what} {str(path)!r}: cannot make folder {str(p)!r}: "
                             f"{exc.strerror or exc}") from None
    return p


def _check_writable(folder: Path, path: Path, what: str):
    ok = os.access(folder, os.W_OK | os.X_OK)
    if ok:
        try:  # the real test (root, read-only file systems): create and drop a file there
            with tempfile.TemporaryFile(dir=folder):
                pass
        except OSError:
            ok = False
    if not ok:
        raise WriteError(f"{what} {str(path)!r}: folder {str(folder)!r} is not writable")


def check_output_file(path, what: str = "output file", *, suffixes=None) -> Path:
    """Refuse, before any work, a file path that cannot be written: an existing directory, a
    name ending in a path separator, a folder that is a file or is not writable, or a suffix not
    in ``suffixes``; missing folders on the way are made. Raises WriteError naming ``what``
    (e.g. the option) and the path."""
    text = os.fspath(path)
    path = Path(text)
    if not text or text.endswith(os.sep) or path.is_dir():
        raise WriteError(f"{what} {text!r}: is a directory, expected a file path")
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise WriteError(f"{what} {text!r}: unsupported suffix {path.suffix!r}; expected one of "
                         f"{sorted(suffixes)}")
    if path.exists() and not path.is_file():
        raise WriteError(f"{what} {text!r}: exists and is not a regular file")
    _check_writable(_parent_folder(path, what), path, what)
    return path


def check_output_dir(path, what: str = "output folder") -> Path:
    """Refuse, before any work, a folder path that cannot be written: an existing file or a
    folder that is not writable; a missing folder is created when writing (its missing parents
    now, under the nearest writable folder that exists). Raises WriteError naming ``what`` and
    the path."""
    text = os.fspath(path)
    path = Path(text)
    if not text:
        raise WriteError(f"{what} {text!r}: expected a folder path")
    if path.exists():
        if not path.is_dir():
            raise WriteError(f"{what} {text!r}: is a file, expected a folder")
        _check_writable(path, path, what)
    else:
        _check_writable(_parent_folder(path, what), path, what)
    return path
