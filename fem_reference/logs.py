"""Quiet libraries: the C toolchain's lines stay out of the log while FFCx compiles forms, and
UFL / FFCx say little, unless the application asks for them (``tissue -v``)."""
from __future__ import annotations

import logging

__all__ = ["CompilerLogFilter", "install_log_filters"]


class CompilerLogFilter(logging.Filter):
    """Keeps the C toolchain's lines out of the log while FFCx compiles forms.

    cffi builds each form's extension with setuptools/distutils, which log "running build_ext"
    and every gcc command line at INFO on the root logger (and set the root level to INFO to
    do so). On the root logger, this filter passes such a record only where the logger
    ``tissue.compiler`` has been given a level at or below the record's (``tissue -v`` sets
    DEBUG); every other record passes."""

    SOURCES = frozenset({"distutils", "_distutils", "setuptools", "cffi"})

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno >= logging.WARNING:
            return True
        from_toolchain = record.name.split(".")[0] in self.SOURCES or (
            record.name == "root"
            and not self.SOURCES.isdisjoint(record.pathname.replace("\\", "/").split("/")))
        shown_from = logging.getLogger("tissue.compiler").level  # NOTSET (0): none shown
        return not from_toolchain or logging.NOTSET < shown_from <= record.levelno


def install_log_filters():
    """Library defaults, left alone where the application set its own levels: UFL and FFCx
    (which log each JIT compilation at INFO) say little, and so does the C toolchain (a
    CompilerLogFilter on the root logger, where setuptools/distutils log, and on the
    toolchain's own loggers, installed once)."""
    for name in ("UFL", "FFCx", "ffcx"):
        if logging.getLogger(name).level == logging.NOTSET:
            logging.getLogger(name).setLevel(logging.WARNING)
    for logger in [logging.getLogger()] + [logging.getLogger(n)
                                           for n in ("distutils", "setuptools", "cffi")]:
        if not any(type(f).__name__ == "CompilerLogFilter" for f in logger.filters):
            logger.addFilter(CompilerLogFilter())
