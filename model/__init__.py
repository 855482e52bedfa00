"""The problem model every solver consumes and what a solve returns: the Case (mesh + material +
boundary conditions + probes + actuators; ``case``, the class ``case_model`` and its parts,
constraints and variants), its TOML file and JSON Schema (``case_file``, ``case_schema``,
``case.schema.json``, ``case_doc``), the rigid tips' shape and contact defaults (``tips``), the
range where answers converge (``converged_range``), the result every solver returns
(``results``), the warnings a caller of an answer must not miss (``answer_warnings``) and
whether a load is symmetric about a mirrored mesh's planes (``symmetry``).
Geometry and meshing are ``meshes``, below; the error tree is ``errors``, below both.
"""
