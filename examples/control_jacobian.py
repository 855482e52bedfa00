"""The control Jacobian J_s at a pushed state, and a finite-difference check of one column.

J_s gives each target's motion (mm) per mm of each actuator's push (seed 000 section III-A). On
the glued-patch phantom the actuators are rigid patches, and J_s at a state is exact from the
tangent stiffness there (``control.jacobian.dirichlet_jacobian``). The script solves the state
(A1 pushed 3 mm, the other patches held), takes the exact tangent
(``fem_reference.tangent_stiffness``), builds J_s, and checks its A1 column against central
differences of two more solves (A1 at 3 mm +- h).

The same with its check from the command line:
``tissue jacobian phantom --size 10 --state-push A1=3``

Run it (about 3 s):

    .venv/bin/python examples/control_jacobian.py
"""
from __future__ import annotations

import numpy as np

import tissue_reference.fem_reference as fr
from tissue_reference.control.jacobian import dirichlet_jacobian, full_pushes
from tissue_reference.model.case import load_case


def main():
    case = load_case("phantom", size=10.0)       # glued patches A1-A4, targets T1-T5
    state = full_pushes(case, {"A1": 3.0})       # every actuator named: the others held at 0
    res = fr.solve(case, pushes=state)
    K = fr.tangent_stiffness(case, res.u, pushes=state).K      # exact tangent at that state
    J = dirichlet_jacobian(case.with_pushes(state), K)
    print(f"J_s at pushes {state} (mm of target per mm of push):")
    print(f"{'':6}" + "".join(f"{a:>9}" for a in J.actuators))
    for row, values in zip(J.rows, J.J):
        print(f"{row:6}" + "".join(f"{v:9.4f}" for v in values))

    h = 0.02                                     # mm
    plus = fr.solve(case, pushes={**state, "A1": 3.0 + h}, initial=res.u)
    minus = fr.solve(case, pushes={**state, "A1": 3.0 - h}, initial=res.u)
    fd = np.concatenate([(plus.probes[t] - minus.probes[t]) / (2 * h) for t in J.targets])
    column = J.J[:, J.actuators.index("A1")]
    err = np.abs(column - fd).max() / np.abs(fd).max()
    print(f"column A1 against central differences (h = {h} mm): max relative difference "
          f"{err:.1e}")


if __name__ == "__main__":
    main()
