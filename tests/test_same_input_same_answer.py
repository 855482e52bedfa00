"""Same input, same answer: a reference solve's verdict (converged, or the load fraction where
Newton gave up) and its answer do not depend on what the process solved before. The solvers
kept for reuse used to start a solve's Newton from the factorization of the previous solve's
last tangent; at a marginal load that decided the verdict.

The marginal load here: A1 pushed 80 mm on the glued phantom at size 10, where Newton gives up
just short of the full load (fraction 0.997 with two BLAS threads). It lies far past the loads
where a glued patch's answer converges; it is chosen because its verdict is fragile, which is
what a test of the verdict's dependence on history needs. Each run is a process of its own,
with the same BLAS thread count (the thread count changes round-off, and a verdict this close
to the edge may hinge on round-off: that is no history)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "meshes" / "cases" / "phantom.toml"
MARGINAL = {"A1": 80.0}
# unrelated solves: other patches, a push that converges after many iterations, one that fails
UNRELATED = [{"A2": 10.0}, {"A3": 30.0}, {"A1": 60.0, "A3": 60.0}]
# the stated tolerance: answers (mm) to ten times Newton's step tolerance (1e-10 mm)
ANSWER_ATOL_MM = 1e-9

SCRIPT = r"""
import json, sys
import numpy as np
from tissue_reference import fem_reference as fr
from tissue_reference.model.case import load_case
from tissue_reference.errors import ConvergenceError

case = load_case(sys.argv[1], size=10.0)

def run(pushes):
    try:
        r = fr.solve(case, pushes=pushes)
        verdict = {"converged": True, "load_fraction": 1.0}
    except ConvergenceError as exc:
        r = exc.last_converged
        verdict = {"converged": False, "load_fraction": exc.load_fraction}
    return dict(verdict, valid=bool(r.valid is not False), u=np.asarray(r.u).tolist(),
                newton=list(r.history["newton_iterations"]),
                trace=list(r.history["iterate_residual"]))

out = {"before": [run(p) for p in json.loads(sys.argv[2])]}
out["marginal"] = run(json.loads(sys.argv[3]))
out["again"] = run(json.loads(sys.argv[3]))
print(json.dumps(out))
"""


def _in_a_process(before):
    env = dict(os.environ, OPENBLAS_NUM_THREADS="2", OMP_NUM_THREADS="2")
    p = subprocess.run([sys.executable, "-c", SCRIPT, str(CASE), json.dumps(before),
                        json.dumps(MARGINAL)], capture_output=True, text=True, env=env,
                       cwd=ROOT, timeout=600, check=False)
    assert p.returncode == 0, p.stderr[-3000:]
    return json.loads(p.stdout.strip().splitlines()[-1])


def _same(a, b, what):
    assert (a["converged"], a["valid"]) == (b["converged"], b["valid"]), what
    assert abs(a["load_fraction"] - b["load_fraction"]) <= 1e-12, what
    assert a["newton"] == b["newton"], f"{what}: Newton iterations per load step differ"
    assert len(a["trace"]) == len(b["trace"]), f"{what}: Newton paths of different lengths"
    np.testing.assert_allclose(a["trace"], b["trace"], rtol=1e-8, err_msg=what)
    gap = float(np.abs(np.subtract(a["u"], b["u"])).max())
    assert gap <= ANSWER_ATOL_MM, f"{what}: answers {gap:.3g} mm apart"


def test_a_marginal_load_gets_the_same_verdict_and_answer_whatever_was_solved_before():
    fresh = _in_a_process([])
    after = _in_a_process(UNRELATED)
    # the unrelated solves did run, one of them to a failure
    assert [r["converged"] for r in after["before"]] == [True, True, False]
    _same(fresh["marginal"], after["marginal"], "fresh process against after unrelated solves")
    _same(fresh["marginal"], fresh["again"], "first solve against the same solve repeated")
    # the load is marginal: Newton either gives up within 1 % of the full load or needs a cut
    m = fresh["marginal"]
    assert m["load_fraction"] > 0.99 and (not m["converged"] or len(m["newton"]) > 1)


def test_every_table1_loop_runs_with_one_blas_thread_count():
    """Serial or in a worker, a table1 loop runs with LOOP_BLAS_THREADS BLAS threads, so the
    thread count of the process that runs it (two here, one in a worker) changes no verdict."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from tissue_reference.control.table1 import LOOP_BLAS_THREADS, run_one

    seen = []

    class Loop:
        def run(self, t, task, settings):
            seen.append({i["internal_api"]: i["num_threads"] for i in threadpool_info()})
            raise _Stop

    class _Stop(Exception):
        pass

    with threadpool_limits(limits=2):
        try:
            run_one(Loop(), "T1", 1, None, None)
        except _Stop:
            pass
        assert seen and set(seen[0].values()) == {LOOP_BLAS_THREADS}
        assert threadpool_info()[0]["num_threads"] == 2   # restored after the loop
    assert "openblas" in seen[0]
