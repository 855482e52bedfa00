"""Observed orders, Richardson extrapolation and Roache's grid convergence index of a scalar
quantity on a sequence of meshes refined by a constant ratio, with the asymptotic-range check
that decides whether an extrapolation may be given at all. Pure numpy: works on any sequence of
values (a reference study, or a user's own solver or field).

For three successive levels q1 (coarse), q2, q3 (fine) the observed order is
p = ln((q1 - q2) / (q2 - q3)) / ln r, defined only when the ratio is positive (monotone
convergence) and both differences exceed round-off (``NOISE_REL`` = 1e-9 of the study's largest
displacement or reaction, at least 1e-10 mm / 1e-8 mN: below the Newton tolerances). A quantity
that is round-off on every level is reported as zero.

A quantity is in the *asymptotic range* when
- with 4 or more meshes: the observed orders of the two finest triples are both defined, agree
  within ``order_tol`` (0.25) and the finest is at least ``MIN_ORDER`` (0.5);
- with exactly 3 meshes (one observed order, nothing to compare it with): that order lies within
  ``order_tol`` of the smooth-solution order (``expected_order``: degree + 1 for a point
  displacement, 2 degree for a reaction); a singular problem (e.g. the rim of a pushed patch)
  converges more slowly and is reported as not asymptotic until a fourth mesh confirms its order.

Only then is the Richardson value q3 + (q3 - q2) / (r^p - 1) given, with Roache's grid convergence
index GCI = Fs |q3 - q2| / (r^p - 1), Fs = 1.25. Otherwise ``extrapolated`` is None and the GCI
is a conservative band: Fs = 3 with p clamped to [0.5, expected order] (p = 0.5 and the larger of
the two finest differences when the differences change sign)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tissue_reference.errors import CaseError

__all__ = [
    "MIN_LEVELS",
    "QuantityConvergence",
    "VectorConvergence",
    "assess",
    "gci",
    "observed_order",
    "richardson",
]

RATIO = 2.0             # uniform refinement halves h
MIN_LEVELS = 3          # meshes needed for one observed order
MIN_ORDER = 0.5         # below this an "order" is stagnation, not convergence
ORDER_TOL = 0.25        # agreement of observed orders (and with the expected one, 3 meshes)
FS_ASYMPTOTIC = 1.25    # Roache's safety factor with a confirmed observed order
FS_OTHERWISE = 3.0      # Roache's safety factor when the order is not confirmed
NOISE_REL = 1e-9        # round-off, relative to the largest displacement / reaction of a study
NOISE_ABS = {"mm": 1e-10, "mN": 1e-8}   # below the Newton tolerances
COMPONENTS = "xyz"


# --------------------------------------------------------------------------- scalar helpers
def observed_order(q_coarse: float, q_mid: float, q_fine: float, *, ratio: float = RATIO,
                   noise: float = 0.0) -> float | None:
    """p = ln((q1 - q2) / (q2 - q3)) / ln(ratio) for three successive levels of a scalar.

    None when the ratio is not positive (the differences change sign: oscillating) or either
    difference is at most ``noise`` (same unit as q)."""
    d1 = float(q_coarse) - float(q_mid)
    d2 = float(q_mid) - float(q_fine)
    if abs(d1) <= noise or abs(d2) <= noise:
        return None
    r = d1 / d2
    if r <= 0:
        return None
    return math.log(r) / math.log(ratio)


def richardson(q_mid: float, q_fine: float, order: float, *, ratio: float = RATIO) -> float:
    """Richardson value q_fine + (q_fine - q_mid) / (ratio^order - 1)."""
    return float(q_fine) + (float(q_fine) - float(q_mid)) / (ratio ** order - 1.0)


def gci(q_mid: float, q_fine: float, order: float, *, ratio: float = RATIO,
        safety: float = FS_ASYMPTOTIC) -> tuple[float, float | None]:
    """Roache's fine-grid convergence index: (absolute Fs |q_fine - q_mid| / (ratio^order - 1),
    relative to |q_fine|, None when q_fine is 0)."""
    a = safety * abs(float(q_fine) - float(q_mid)) / (ratio ** order - 1.0)
    return a, (a / abs(float(q_fine)) if q_fine != 0 else None)


@dataclass(frozen=True)
class QuantityConvergence:
    """One scalar quantity (unit ``unit``: mm or mN) on the levels of a study, coarse to fine.

    orders: observed order of each triple of successive levels (None where undefined).
    asymptotic: the module docstring's test passed; ``reason`` says why or why not.
    extrapolated: Richardson value (None unless asymptotic). gci / gci_rel: uncertainty of the
    finest value (absolute, unit; relative), with safety factor ``safety_factor``.
    """

    name: str
    unit: str
    values: tuple
    h: tuple
    orders: tuple
    expected_order: float
    asymptotic: bool
    reason: str
    extrapolated: float | None
    gci: float | None
    gci_rel: float | None
    safety_factor: float

    @property
    def observed_order(self) -> float | None:
        """The order from the three finest levels (None where undefined)."""
        return self.orders[-1] if self.orders else None

    def to_json_dict(self) -> dict:
        u = self.unit
        return {"values_" + u: list(self.values), "h_mm": list(self.h),
                "observed_order": self.observed_order, "observed_orders": list(self.orders),
                "expected_order": self.expected_order, "asymptotic": self.asymptotic,
                "reason": self.reason, "extrapolated_" + u: self.extrapolated,
                "gci_" + u: self.gci, "gci_rel": self.gci_rel,
                "safety_factor": self.safety_factor}


def assess(values, h, *, expected_order: float, order_tol: float = ORDER_TOL,
           ratio: float = RATIO, noise: float | None = None, name: str = "q",
           unit: str = "mm") -> QuantityConvergence:
    """Observed orders, asymptotic-range test, Richardson value and GCI of a scalar sequence
    ``values`` (coarse to fine, unit ``unit``) on meshes of size ``h`` (mm) refined by ``ratio``.
    noise: differences at most this large (unit) are round-off (default NOISE_REL max |q|).
    See the module docstring for the rules. Needs at least 3 values.

    Parameters
    ----------
    values : sequence of float
        The quantity on each mesh, coarse to fine (``unit``).
    h : sequence of float
        The meshes' sizes (mm).
    expected_order : float
        The discretization's formal order (e.g. degree + 1 for displacements).
    order_tol : float
        How far the observed order may be from ``expected_order`` in the asymptotic range.
    ratio : float
        Refinement ratio between levels.
    noise : float or None
        Differences at most this large (``unit``) are round-off; None: NOISE_REL max |q|.
    name : str
        The quantity's name in messages.
    unit : str
        The quantity's unit (e.g. "mm", "mN").

    Returns
    -------
    QuantityConvergence
        Observed orders, ``asymptotic`` and its ``reason``, ``extrapolated`` and ``gci`` (unit)
        with ``gci_rel``.

    Raises
    ------
    CaseError
        For fewer than 3 values.
    """
    q = [float(v) for v in values]
    if len(q) < MIN_LEVELS:
        raise CaseError(f"{name}: an observed order needs at least {MIN_LEVELS} levels, "
                        f"got {len(q)}")
    if noise is None:
        noise = NOISE_REL * max(abs(v) for v in q)
    if max(abs(v) for v in q) <= noise:
        return QuantityConvergence(
            name, unit, tuple(q), tuple(float(x) for x in h), (None,) * (len(q) - 2),
            float(expected_order), False, f"zero: |q| <= {noise:.3g} {unit} (round-off) on "
            f"every level", None, None, None, FS_OTHERWISE)
    orders = tuple(observed_order(q[k], q[k + 1], q[k + 2], ratio=ratio, noise=noise)
                   for k in range(len(q) - 2))
    p = orders[-1]
    d_fine, d_prev = q[-2] - q[-1], q[-3] - q[-2]
    if abs(d_fine) <= noise and abs(d_prev) <= noise:
        ok, why = False, "the values do not change between levels (differences at round-off)"
    elif p is None:
        why = "the differences between levels change sign (oscillating)" \
            if d_fine * d_prev < 0 else "a difference between levels is at round-off"
        ok, why = False, f"{why}: {d_prev:+.3g}, {d_fine:+.3g} {unit}"
    elif len(orders) >= 2:
        prev = orders[-2]
        if prev is None:
            ok, why = False, f"order {p:.2f} from the finest levels, none from the coarser triple"
        elif abs(p - prev) > order_tol:
            ok, why = False, (f"observed orders {prev:.2f} then {p:.2f} differ by more than "
                              f"{order_tol:g}")
        elif p < MIN_ORDER:
            ok, why = False, f"observed order {p:.2f} < {MIN_ORDER:g} (stagnating)"
        else:
            ok, why = True, f"observed orders {prev:.2f} and {p:.2f} agree within {order_tol:g}"
    elif abs(p - expected_order) > order_tol:
        ok, why = False, (f"one observed order ({len(q)} meshes): {p:.2f}, not within "
                          f"{order_tol:g} of the smooth-solution order {expected_order:g}")
    else:
        ok, why = True, (f"observed order {p:.2f} within {order_tol:g} of the smooth-solution "
                         f"order {expected_order:g}")
    if ok:
        extra = richardson(q[-2], q[-1], p, ratio=ratio)
        g, g_rel = gci(q[-2], q[-1], p, ratio=ratio, safety=FS_ASYMPTOTIC)
        fs = FS_ASYMPTOTIC
    else:
        extra = None
        fs = FS_OTHERWISE
        if p is None:
            p_used, diff = MIN_ORDER, max(abs(d_fine), abs(d_prev))
        else:
            p_used, diff = min(max(p, MIN_ORDER), max(expected_order, MIN_ORDER)), abs(d_fine)
        g = fs * diff / (ratio ** p_used - 1.0)
        g_rel = g / abs(q[-1]) if q[-1] != 0 else None
    return QuantityConvergence(name, unit, tuple(q), tuple(float(x) for x in h), orders,
                               float(expected_order), ok, why, extra, g, g_rel, fs)


@dataclass(frozen=True)
class VectorConvergence:
    """A probe displacement (mm) or a region's reaction (mN) on every level.

    values: (levels, gdim). dominant: the component with the largest |value| on the finest mesh.
    components: label ("x", "y", "z") -> QuantityConvergence for the components of at least
    ``component_floor`` times the dominant magnitude (the dominant one always among them).
    """

    name: str
    unit: str
    values: np.ndarray
    dominant: str
    components: dict

    @property
    def headline(self) -> QuantityConvergence:
        return self.components[self.dominant]

    def to_json_dict(self) -> dict:
        d = {"component": self.dominant, **self.headline.to_json_dict(),
             "vector_" + self.unit: self.values.tolist(),
             "components": {k: v.to_json_dict() for k, v in self.components.items()}}
        return d


def vector_convergence(name, unit, values, h, expected, order_tol, floor, noise, *,
                       ratio: float = RATIO) -> VectorConvergence:
    v = np.asarray(values, dtype=np.float64)
    fine = np.abs(v[-1])
    k = int(np.argmax(fine))
    comps = {}
    for c in range(v.shape[1]):
        if c == k or (fine[c] >= floor * fine[k] and fine[k] > noise):
            comps[COMPONENTS[c]] = assess(v[:, c], h, expected_order=expected, order_tol=order_tol,
                                          ratio=ratio, noise=noise, name=f"{name} {COMPONENTS[c]}", unit=unit)
    return VectorConvergence(name, unit, v, COMPONENTS[k], comps)
