"""tissue-reference: FEniCSx Neo-Hookean ground truth, ADMM and Mass Tensor fast solvers, exact
Jacobians and a push-only MPC for soft-tissue simulation and control.

The one installed top-level name. Its layers are subpackages, each importing only those before
it: ``tissue_reference.errors`` (the exception tree), ``.meshes``, ``.model`` (the Case and the
results), ``.fem_reference``, ``.solvers``, ``.control``, ``.implant``, ``.verification`` and
``.tissue`` (the command line).
Installed, they are folders inside this package; in the repository they are the top-level folders
beside this one (pyproject.toml's ``package-dir`` maps them), and this folder holds a symbolic
link to each, so that a checkout on ``sys.path`` (``PYTHONPATH=.``), editors and type checkers
find them under their installed names.
"""
