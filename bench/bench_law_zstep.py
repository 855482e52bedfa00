"""Per-round cost of the numpy z-step of the invariant laws (``kernel_array.LawZStep``) on a
batch of elements, in one run: psi, P and A of each law from one ``Law.evaluate`` (the z-step's
path) against the three separate ``psi_J``, ``stress`` and ``tangent`` calls at the same
gradients (each computing the invariants and their derivatives anew), and the whole z-step with
each. Best of ``--repeat`` (ms), one thread.

    python bench/bench_law_zstep.py [--elements 4000] [--repeat 15] [--laws mooney-rivlin ...]
"""
import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import time

import numpy as np

from tissue_reference.model.case import Material
from tissue_reference.solvers.admm.kernel_array import LawZStep, aos, soa
from tissue_reference.solvers.admm.mechanics import INVARIANT_LAWS, Law, LawValues

PARAMS = {"mooney-rivlin": {"c1": 0.7, "c2": 0.3, "k": 20.0},
          "yeoh": {"c1": 1.0, "c2": -0.1, "c3": 0.02, "k": 20.0}}


class SeparateCalls:
    """A law whose ``evaluate`` calls ``psi_J``, ``stress`` and ``tangent`` one by one."""

    def __init__(self, law):
        self.law = law

    def evaluate(self, H, psi=True, stress=True, tangent=True):
        e, J = self.law.psi_J(H) if psi else (None, None)
        P = self.law.stress(H)[0] if stress else None
        A = self.law.tangent(H) if tangent else None
        return LawValues(e, J, P, A)

    def __getattr__(self, name):
        return getattr(self.law, name)


class Ops:
    def __init__(self, law):
        self.law, self.d = law, law.d


def best(repeat, fn, *args):
    t = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn(*args)
        t.append(time.perf_counter() - t0)
    return 1e3 * min(t)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", type=int, default=4000)
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--laws", nargs="+", default=list(INVARIANT_LAWS))
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    m, d = args.elements, 3
    H = rng.normal(scale=0.1, size=(m, d, d))
    Fhat = soa(H + np.eye(d) + rng.normal(scale=0.02, size=(m, d, d)))
    print(f"{m} elements (3D), best of {args.repeat}; ms per call")
    print(f"{'law':24s} {'separate':>9s} {'evaluate':>9s} {'ratio':>6s} "
          f"{'z-step old':>11s} {'z-step new':>11s} {'ratio':>6s} {'max |dF|':>9s}")
    for model in args.laws:
        p = PARAMS.get(model, {"E": 6.0, "nu": 0.45})
        law = Law(Material(model, **p), d)
        old = SeparateCalls(law)
        t_sep = best(args.repeat, old.evaluate, H)
        t_one = best(args.repeat, law.evaluate, H)
        out = {}
        times = {}
        for name, lw in (("old", old), ("new", law)):
            z = LawZStep(Ops(lw), 10.0)
            E = soa(H + np.eye(d))
            Enew = np.empty_like(E)
            times[name] = best(args.repeat, z, Fhat, E, Enew)
            out[name] = aos(Enew).copy()
        diff = float(np.abs(out["old"] - out["new"]).max())
        print(f"{model:24s} {t_sep:9.2f} {t_one:9.2f} {t_sep / t_one:6.2f} "
              f"{times['old']:11.2f} {times['new']:11.2f} {times['old'] / times['new']:6.2f} "
              f"{diff:9.1e}")


if __name__ == "__main__":
    main()
