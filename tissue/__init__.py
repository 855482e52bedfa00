"""Application layer: the ``tissue`` command line, verification runs and reports.

It is the one layer that may import every other (meshes, fem_reference, solvers, control,
implant); each sub-command lives in a ``cmd_*.py`` module exposing ``add_parser(subparsers)``.
"""
