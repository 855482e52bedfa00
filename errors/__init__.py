"""Exception hierarchy of the toolkit, and its warning (``TissueWarning``). Every message names the
file, region or value at fault. The bottom layer: it imports nothing of the project, so that
meshing, the Case model and the solvers all raise from one tree."""

__all__ = [
    "AccuracyNotReached",
    "CaseError",
    "CaseReadError",
    "ConvergenceError",
    "MeshQualityError",
    "ReadError",
    "SolverDivergedError",
    "TissueError",
    "TissueWarning",
    "WriteError",
]


class TissueError(Exception):
    """Base class of every error this toolkit raises on purpose."""


class ReadError(TissueError):
    """A file could not be read (missing, unreadable, wrong format)."""


class WriteError(TissueError):
    """A file could not be written."""


class CaseError(TissueError, ValueError):
    """The problem description is inconsistent (unknown region, bad material value, ...)."""


class CaseReadError(CaseError, ReadError):
    """A case file, or the mesh file it names, could not be read (missing, a directory, not TOML,
    not a mesh): both a CaseError and a ReadError."""


class NotModeledError(CaseError):
    """A solver does not model part of the problem (e.g. a fast solver and a rigid tip's
    contact): the problem is fine, this solver cannot answer it."""


class MeshQualityError(CaseError):
    """The mesh has inverted or zero-volume cells."""


class ConvergenceError(TissueError, RuntimeError):
    """A nonlinear solve did not converge. ``last_converged`` holds the last good state;
    ``trajectory``, for a time integration, what it computed before the step that failed
    (None otherwise)."""

    def __init__(self, message, *, load_fraction=0.0, last_converged=None, trajectory=None):
        super().__init__(message)
        self.load_fraction = load_fraction
        self.last_converged = last_converged
        self.trajectory = trajectory


class SolverDivergedError(ConvergenceError):
    """A fast solver diverged (NaN, inverted element, residual growth)."""


class AccuracyNotReached(TissueError):
    """``fem_reference.adapt.solve_to_accuracy`` stopped at ``max_dofs`` before every probe met the accuracy.
    ``result`` holds the AdaptiveResult of the steps done (None when not even the first fitted)."""

    def __init__(self, message, *, result=None):
        super().__init__(message)
        self.result = result


class TissueWarning(UserWarning):
    """An answer that came back but should not be taken at face value: not valid (inverted
    cells, runaway growth), past the loads where answers converge (no error bar), or with an
    estimated error above 2 %. The Python API warns with it; the command line prints the same
    lines itself. ``warnings.simplefilter("error", TissueWarning)`` makes each an exception."""
