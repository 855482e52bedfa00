"""tissue-reference: FEniCSx Neo-Hookean ground truth, ADMM and Mass Tensor fast solvers, exact
Jacobians and a push-only MPC for soft-tissue simulation and control.

The one installed top-level name. Its layers are subpackages: ``tissue_reference.meshes``,
``.fem_reference``, ``.solvers``, ``.control``, ``.implant`` and ``.tissue`` (the command line).
Installed, they are folders inside this package; in the repository they are the top-level folders
beside this one (pyproject.toml's ``package-dir`` maps them), so a checkout on ``sys.path``
(``PYTHONPATH=.``) finds them there.
"""
from pathlib import Path as _Path

_here = _Path(__file__).resolve().parent
if not (_here / "meshes").is_dir() and (_here.parent / "meshes" / "__init__.py").is_file() \
        and (_here.parent / "pyproject.toml").is_file():
    __path__.append(str(_here.parent))
del _Path, _here
