"""Application layer: the ``tissue`` command line and its reports.

It is the one layer that may import every other (meshes, fem_reference, solvers, control,
implant, verification); each sub-command lives in a ``cmd_*.py`` module exposing
``add_parser(subparsers)``.
"""
