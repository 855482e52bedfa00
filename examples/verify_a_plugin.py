"""Score a solver that is not part of the toolkit against the reference.

``examples/linear_plugin.py`` is such a solver: small-strain linear elasticity in numpy, following
the plugin protocol (``solve(case, pushes, **options)`` returns the (n, 3) vertex displacement,
mm). ``verification.verify.verify`` solves the reference on the same mesh and scores the
plugin: max and RMS vertex error, probe errors, volume norms, and its speed against the
reference's.

The plugin returns a bare array, so it states no material law and is scored against the case's
own (Neo-Hookean): its error then holds the law difference. Wrapped to declare
``extra["model"] = "linear-elastic"``, the same answer is scored against the linear-elastic
reference, and the law difference is reported apart (``law_difference_mm``).

Run it (about 3 s); the same from the command line:
``tissue verify phantom --size 10 --push A1=2 --solvers examples/linear_plugin.py:solve``

    .venv/bin/python examples/verify_a_plugin.py
"""
from __future__ import annotations

from pathlib import Path

from tissue_reference.model.case import load_case
from tissue_reference.verification.plugins import resolve_solver
from tissue_reference.verification.verify import verify

PLUGIN = f"{Path(__file__).with_name('linear_plugin.py')}:solve"   # "file.py:function"


def linear_declared(case, pushes):
    """The same solver (loaded from its file), now saying which law it solves."""
    u = resolve_solver(PLUGIN).function(case, pushes)
    return {"u": u, "extra": {"model": "linear-elastic"}}


def main():
    case = load_case("phantom", size=10.0)       # the glued-patch phantom, coarse: 1.7k tets
    out = verify(case, {"A1": 2.0}, solvers=[PLUGIN, linear_declared])
    for name, s in out["solvers"].items():
        print(f"{Path(name).name}:")
        print(f"  declares the law: {s['model']}; scored against the {s['reference_model']} "
              f"reference (P{s['reference_discretization']['degree']})")
        print(f"  max vertex error {s['max_vertex_error_mm']:.3g} mm, "
              f"RMS {s['rms_vertex_error_mm']:.3g} mm, T1 {s['probe_error_mm']['T1']:.3g} mm")
        print(f"  speed: {s['speedup_vs_reference']:.2f}x the reference's "
              f"({s['wall_time_s']:.3f} s against {s['reference_wall_time_s']:.3f} s)")
        if "law_difference_mm" in s:
            print(f"  law difference (not solver error): {s['law_difference_mm']:.3g} mm")


if __name__ == "__main__":
    main()
