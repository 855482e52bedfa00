"""Verification layer: candidates scored against the reference (``verify``: the built-in fast
solvers, anyone's solver through ``plugins``, displacement fields through ``scoring``) and the
verification suite of problems with answers known without finite elements (``suite``, its
answers in ``closed_forms``) and seed 000's model validation (``sweep``: each actuator alone in
steps, every target's error per axis against the reference, its Fig. 7).

It imports meshes, fem_reference, solvers and control, never the command line (``tissue``),
which calls it and writes the reports of what it returns.
"""
