"""``Polisher``: the polish that finishes each ADMM solve of a ``solve`` (``driver``): Newton
steps (``polish.newton``), or chord steps on the tangent at rest (``chord``) with the Newton
polish taking over from their best iterate where they do not converge. It keeps the tangent at
rest factorized once per solve and counts what it did for ``SolveResult.extra``."""
from __future__ import annotations

from .chord import chord
from .polish import newton, rest_factor


class Polisher:
    """The polish steps of one solve and their counts.

    Parameters
    ----------
    ops : AdmmOperators
        The solve's operators (``operators.prepare``).
    opts : SolveOptions
        The solve's resolved options: ``use_chord``, ``polish_tol_mm`` (mm),
        ``polish_max_iter``, ``callback`` and ``factorize`` are read.
    hist : dict
        The solve's iteration history; each step appends its largest step (mm) to
        ``hist["newton_step_mm"]``.
    tips_at : callable
        tips_at(s) -> the rigid tips' ends at load fraction s (None without tips).
    """

    def __init__(self, ops, opts, hist, tips_at):
        self.ops, self.opts, self.hist, self.tips_at = ops, opts, hist, tips_at
        self.chord_steps = 0
        self.chord_stats = {"refactorizations": 0}
        self.fallbacks = []
        self._rest = None

    def rest(self):
        """The tangent at rest and its factorization, once per solve (kept with the operators
        when small: ``polish.rest_factor``).

        Returns
        -------
        tuple
            (the element matrices Ke at rest, mN/mm; the factorization of the reduced
            tangent at rest, with ``solve(b)``).
        """
        if self._rest is None:
            self._rest = rest_factor(self.ops, self.opts.factorize)
        return self._rest

    def step(self, u, f, inertia, it0, tol=None, s=1.0):
        """Polish ``u`` at the external forces ``f``: chord steps then, if they fail, Newton from
        their best iterate (chord polish), or Newton steps.

        Parameters
        ----------
        u : ndarray
            Node-major displacement (mm) to start from.
        f : ndarray
            Node-major external forces (mN).
        inertia : tuple or None
            (M / dt^2, u_tilde) of an implicit-Euler step (kg/s^2, mm); None: quasi-static.
        it0 : int
            Iterations before this polish (the callback's and the history's count).
        tol : float or None
            Largest step (mm) that ends the polish; None: ``opts.polish_tol_mm``.
        s : float
            Load fraction, where the rigid tips are (``tips_at``).

        Returns
        -------
        tuple
            (u, mm node-major; the polish iterations taken, chord and Newton).
        """
        opts = self.opts
        tol = opts.polish_tol_mm if tol is None else tol
        k = 0
        if opts.use_chord:
            u, k, ok = chord(self.ops, u, f, self.rest()[1], tol_mm=tol,
                             max_iter=opts.polish_max_iter, it0=it0, hist=self.hist,
                             callback=opts.callback, tips=self.tips_at(s),
                             factorize=opts.factorize, stats=self.chord_stats)
            self.chord_steps += k
            if ok:
                return u, k
            self.fallbacks.append(f"load fraction {s:.4g}: chord steps did not converge in {k}; "
                                  f"Newton polish from their best iterate")
        u, kn = newton(self.ops, u, f, inertia, tol_mm=tol, max_iter=opts.polish_max_iter,
                       it0=it0 + k, hist=self.hist, callback=opts.callback,
                       factorize=opts.factorize, tips=self.tips_at(s))
        return u, k + kn

    def extra(self) -> dict:
        """What the chord polish did, for ``SolveResult.extra`` (empty for the Newton polish).

        Returns
        -------
        dict
            "polish": "chord", "chord_iterations", "chord_refactorizations" and
            "chord_fallbacks" (one line per load step the Newton polish finished).
        """
        if not self.opts.use_chord:
            return {}
        return {"polish": "chord", "chord_iterations": self.chord_steps,
                "chord_refactorizations": self.chord_stats["refactorizations"],
                "chord_fallbacks": self.fallbacks}
