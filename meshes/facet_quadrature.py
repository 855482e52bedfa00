"""Quadrature rules on a simplex facet (an edge in 2D, a triangle in 3D) for the contact
integrals: the rules the reference's contact forms use, in numpy, so that a solver without
FEniCSx integrates the same discrete contact energy.

``nodal_rule``: one point per Lagrange node of a facet of the given degree (the lumped rule of
the P1 facets through the nodes). ``gauss_rule``: the default Gauss rule of a degree on the
reference facet as basix 0.5 (FEniCSx) makes it: Gauss-Legendre on an edge (ceil((degree + 1)
/ 2) points), Xiao and Gimbutas's symmetric rules on a triangle (their published tables,
2010, as basix ships them, degrees 1-8; ``tests/test_facet_quadrature.py`` compares them with
basix where it is installed).

Reference facets: the edge [0, 1]; the triangle (0, 0), (1, 0), (0, 1) (area 1/2). Weights sum
to the reference measure."""
from __future__ import annotations

import numpy as np

__all__ = ["GAUSS_DEGREES", "facet_rule", "gauss_rule", "nodal_rule"]

# degree -> ((x, y, weight), ...) on the reference triangle
_TRIANGLE_RULES = {
    1: ((
        (0.3333333333333333, 0.3333333333333333, 0.5),
    )),
    2: ((
        (0.16666666666666666, 0.16666666666666666, 0.16666666666666666),
        (0.16666666666666666, 0.6666666666666666, 0.16666666666666666),
        (0.6666666666666666, 0.16666666666666666, 0.16666666666666666),
    )),
    3: ((
        (0.659027622374092, 0.231933368553031, 0.08333333333333333),
        (0.659027622374092, 0.109039009072877, 0.08333333333333333),
        (0.231933368553031, 0.659027622374092, 0.08333333333333333),
        (0.231933368553031, 0.109039009072877, 0.08333333333333333),
        (0.109039009072877, 0.659027622374092, 0.08333333333333333),
        (0.109039009072877, 0.231933368553031, 0.08333333333333333),
    )),
    4: ((
        (0.816847572980459, 0.091576213509771, 0.054975871827661),
        (0.091576213509771, 0.816847572980459, 0.054975871827661),
        (0.091576213509771, 0.091576213509771, 0.054975871827661),
        (0.10810301816807, 0.445948490915965, 0.1116907948390055),
        (0.445948490915965, 0.10810301816807, 0.1116907948390055),
        (0.445948490915965, 0.445948490915965, 0.1116907948390055),
    )),
    5: ((
        (0.3333333333333333, 0.3333333333333333, 0.1125),
        (0.7974269853530872, 0.10128650732345633, 0.06296959027241358),
        (0.10128650732345633, 0.7974269853530872, 0.06296959027241358),
        (0.10128650732345633, 0.10128650732345633, 0.06296959027241358),
        (0.05971587178976981, 0.47014206410511505, 0.06619707639425308),
        (0.47014206410511505, 0.05971587178976981, 0.06619707639425308),
        (0.47014206410511505, 0.47014206410511505, 0.06619707639425308),
    )),
    6: ((
        (0.873821971016996, 0.063089014491502, 0.0254224531851035),
        (0.063089014491502, 0.873821971016996, 0.0254224531851035),
        (0.063089014491502, 0.063089014491502, 0.0254224531851035),
        (0.501426509658179, 0.24928674517091, 0.0583931378631895),
        (0.24928674517091, 0.501426509658179, 0.0583931378631895),
        (0.24928674517091, 0.24928674517091, 0.0583931378631895),
        (0.636502499121399, 0.310352451033785, 0.041425537809187),
        (0.636502499121399, 0.053145049844816, 0.041425537809187),
        (0.310352451033785, 0.636502499121399, 0.041425537809187),
        (0.310352451033785, 0.053145049844816, 0.041425537809187),
        (0.053145049844816, 0.636502499121399, 0.041425537809187),
        (0.053145049844816, 0.310352451033785, 0.041425537809187),
    )),
    7: ((
        (0.47319565368925104, 0.47319565368925104, 0.02659041664838023),
        (0.057797640054506494, 0.057797640054506494, 0.020459085197028434),
        (0.24166360639724743, 0.24166360639724743, 0.06386262428056692),
        (0.47319565368925104, 0.05360869262149792, 0.02659041664838023),
        (0.057797640054506494, 0.884404719890987, 0.020459085197028434),
        (0.24166360639724743, 0.5166727872055051, 0.06386262428056692),
        (0.05360869262149792, 0.47319565368925104, 0.02659041664838023),
        (0.884404719890987, 0.057797640054506494, 0.020459085197028434),
        (0.5166727872055051, 0.24166360639724743, 0.06386262428056692),
        (0.046971206130085534, 0.2593390118657857, 0.027877270270345547),
        (0.6936897820041288, 0.046971206130085534, 0.027877270270345547),
        (0.2593390118657857, 0.6936897820041288, 0.027877270270345547),
        (0.2593390118657857, 0.046971206130085534, 0.027877270270345547),
        (0.6936897820041288, 0.2593390118657857, 0.027877270270345547),
        (0.046971206130085534, 0.6936897820041288, 0.027877270270345547),
    )),
    8: ((
        (0.3333333333333333, 0.3333333333333333, 0.0721578038388936),
        (0.17056930775176027, 0.17056930775176027, 0.05160868526735912),
        (0.4592925882927231, 0.4592925882927231, 0.04754581713364232),
        (0.05054722831703107, 0.05054722831703107, 0.01622924881159904),
        (0.17056930775176027, 0.6588613844964795, 0.05160868526735912),
        (0.4592925882927231, 0.08141482341455375, 0.04754581713364232),
        (0.05054722831703107, 0.8989055433659379, 0.01622924881159904),
        (0.6588613844964795, 0.17056930775176027, 0.05160868526735912),
        (0.08141482341455375, 0.4592925882927231, 0.04754581713364232),
        (0.8989055433659379, 0.05054722831703107, 0.01622924881159904),
        (0.008394777409957675, 0.26311282963463806, 0.013615157087217498),
        (0.7284923929554044, 0.008394777409957675, 0.013615157087217498),
        (0.26311282963463806, 0.7284923929554044, 0.013615157087217498),
        (0.26311282963463806, 0.008394777409957675, 0.013615157087217498),
        (0.7284923929554044, 0.26311282963463806, 0.013615157087217498),
        (0.008394777409957675, 0.7284923929554044, 0.013615157087217498),
    )),
}

GAUSS_DEGREES = tuple(sorted(_TRIANGLE_RULES))
"""The degrees of the Gauss rules on a facet (``gauss_rule``)."""


def nodal_rule(fdim: int, degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Points and weights on the reference facet (interval or triangle) at the nodes of the
    Lagrange element of ``degree``, each weighted by its share of the facet split into degree^fdim
    sub-simplices (each sub-simplex gives its measure equally to its vertices): the lumped rule
    of the P1 facets through the nodes. One point per displacement node: the penalty constrains
    each surface node once (degree 2 triangle: corners 1/24, edge midpoints 1/8)."""
    k = degree
    if fdim == 1:
        pts = np.arange(k + 1, dtype=float)[:, None] / k
        w = np.full(k + 1, 1.0 / k)
        w[[0, -1]] = 0.5 / k
        return pts, w
    index = {(i, j): n for n, (i, j) in enumerate((i, j) for j in range(k + 1)
                                                 for i in range(k + 1 - j))}
    w = np.zeros(len(index))
    area = 0.5 / k ** 2 / 3.0
    for (i, j) in index:
        if i + j <= k - 1:
            for v in ((i, j), (i + 1, j), (i, j + 1)):
                w[index[v]] += area
        if i + j <= k - 2:
            for v in ((i + 1, j), (i, j + 1), (i + 1, j + 1)):
                w[index[v]] += area
    pts = np.array([[i / k, j / k] for (i, j) in index])
    return pts, w


def gauss_rule(fdim: int, degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Points (q, fdim) and weights (q,) of the Gauss rule of ``degree`` (1-8) on the
    reference facet, as FEniCSx (basix 0.5) makes it by default (module docstring)."""
    if degree not in _TRIANGLE_RULES:
        raise ValueError(f"Gauss rules on a facet have degrees {list(GAUSS_DEGREES)}, "
                         f"got {degree!r}")
    if fdim == 1:
        x, w = np.polynomial.legendre.leggauss((degree + 2) // 2)
        return (0.5 * (x + 1.0))[:, None], 0.5 * w
    t = np.array(_TRIANGLE_RULES[degree])
    return t[:, :2].copy(), t[:, 2].copy()


def facet_rule(fdim: int, rule) -> tuple[np.ndarray, np.ndarray]:
    """The contact rule ``rule`` ("nodal", or a Gauss degree) on a P1 facet of dimension
    ``fdim``: points (q, fdim) and weights (q,) on the reference facet."""
    return nodal_rule(fdim, 1) if rule == "nodal" else gauss_rule(fdim, int(rule))
