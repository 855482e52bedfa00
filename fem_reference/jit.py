"""How the reference compiles its forms: every UFL form goes through ``compile_form`` (and every
expression evaluated at points through ``compile_expression``), which pass the C compiler's
flags (``JIT_PARAMS``, read at each call) to dolfinx's just-in-time compiler explicitly.

Two reasons to fix them here rather than take dolfinx's defaults:
- speed: ``-fno-math-errno`` lets the compiler inline sqrt and skip errno bookkeeping around the
  other libm calls, and ``-fno-trapping-math`` lets it schedule floating-point operations as if
  no operation traps. Neither reorders arithmetic, and NaN and inf propagate as before (no
  -ffast-math: the residual's NaN check needs them). On the quarter tip phantom (P2, 38k unknowns) the Neo-Hookean tangent assembles
  in 0.24 s instead of 0.29 s and the residual in 0.015 s instead of 0.029 s, and a solve of
  all four tips to 5, 10, 12.5 mm spends 5.2-5.9 / 8.3 / 5.5 s in assembly instead of
  8.5-8.7 / 13.0 / 8.7 s, with forces and targets equal to 12 digits
  (bench/bench_default_accuracy.py times the whole solve);
- reproducibility: dolfinx also reads flags from ``dolfinx_jit_parameters.json`` in the
  working directory and in ``~/.config/dolfinx``; flags passed explicitly take precedence, so
  the same input compiles the same kernels wherever it runs.
"""
from __future__ import annotations

import dolfinx.fem

__all__ = ["JIT_PARAMS", "compile_expression", "compile_form"]

JIT_PARAMS = {"cffi_extra_compile_args": ["-O2", "-g0", "-fno-math-errno", "-fno-trapping-math"]}
"""dolfinx's JIT parameters for every form of the reference (dolfinx.jit.ffcx_jit)."""


def compile_form(form):
    """``dolfinx.fem.form(form)`` compiled with ``JIT_PARAMS``."""
    return dolfinx.fem.form(form, jit_params=JIT_PARAMS)


def compile_expression(expr, points):
    """``dolfinx.fem.Expression(expr, points)`` compiled with ``JIT_PARAMS``."""
    return dolfinx.fem.Expression(expr, points, jit_params=JIT_PARAMS)
