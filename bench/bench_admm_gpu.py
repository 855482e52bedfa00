"""ADMM time per iteration on the CPU path (compiled element kernel, SuperLU or AMG-CG x-step)
and on the array backend (element pass, and the CPU path's AMG-CG x-step or else Jacobi-CG,
written against numpy/CuPy: on the GPU when CuPy finds one, else on numpy, labelled "array on
numpy (no GPU)"), on boxes of about 1e4, 1e5 and 1e6 tetrahedra
(``meshes.builders.structured_box``, n^3 cubes of six tets: the same meshes on every machine,
gmsh not needed; ``--mesher gmsh``: ``meshes.builders.box``); the growth exponent of the
time per iteration with the number of tets (log-log least squares), memory, and the ratio of the
two backends at each size, all measured in this one run.

    .venv/bin/python bench/bench_admm_gpu.py [--tets 1e4 1e5 1e6] [--iters 20] [--repeats 2]
        [--mesher structured|gmsh] [--agreement DATA.npz]

``--agreement``: first the array backend's agreement with the CPU kernel on the phantom
(``admm_gpu_agreement.py``, whose file carries the meshes and the reference answer to a machine
without gmsh or dolfinx).

The CPU path's element loop is the compiled C kernel where cffi and a C compiler are present,
else its numpy loop; the first line says which.

Case: box 10 x 10 x 10 mm, Neo-Hookean (E 6 kPa, nu 0.45), xmin fixed, xmax moved by
(1.0, 0.5, -0.3) mm in one load step. Each timed solve starts from the ADMM state after 10
iterations and runs ``--iters`` iterations with no stopping (tol 1e-30), no lift, no polish; the
time per iteration is the solver's own per-iteration clock (``history["admm_clock_s"]``) from
its third iteration on (the GPU is synchronized every iteration: the residual maxima are read
back). Memory: host peak of setup + 3 iterations (tracemalloc, plus SuperLU's factor, not
traced), and for the GPU the CuPy memory pool after the solve. A size whose estimated host
memory (from the per-tet peak of the previous size, or 10 KiB per tet) exceeds the available
memory is skipped. Units: ms, MiB. Wall clock on one thread (OPENBLAS_NUM_THREADS=1 unless set);
on a shared machine times are noisy: each figure is the minimum (and median) of the repeats.
"""
from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import math
import time
import tracemalloc

import numpy as np

from tissue_reference.meshes.builders import CELLS_PER_VOLUME, box, structured_box
from tissue_reference.model.case import Boundary, Case, Material
from tissue_reference.solvers import admm
from tissue_reference.solvers.admm import kernel_c, operators

DEFAULT_BYTES_PER_TET = 10 * 1024  # host memory guess before a size has been measured


def _load():
    return "load average {:.2f} {:.2f} {:.2f} on {} CPUs".format(*os.getloadavg(), os.cpu_count())


def _available_bytes():
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def box_size_for(tets):
    """Characteristic length (mm) of the 10 mm box with about ``tets`` tetrahedra."""
    return (CELLS_PER_VOLUME[3] * 1000.0 / tets) ** (1.0 / 3.0)


def build_box(tets, mesher):
    """(mesh, label) of the 10 mm box with about ``tets`` tetrahedra."""
    if mesher == "gmsh":
        h = box_size_for(tets)
        return box(h), f"gmsh, size {h:.3g} mm"
    n = max(1, round((tets / 6.0) ** (1.0 / 3.0)))
    return structured_box(n), f"structured, {n}^3 cubes"


def box_case(mesh):
    return Case(mesh, Material(model="neo-hookean", E=6.0, nu=0.45),
                boundaries=[Boundary("xmin", "fixed"),
                            Boundary("xmax", "displacement", value=(1.0, 0.5, -0.3))])


def array_device():
    """("gpu", label) when CuPy finds a GPU, else ("array-cpu", label with the reason)."""
    try:
        admm.array_module("gpu")
        import cupy

        name = cupy.cuda.runtime.getDeviceProperties(0)["name"]
        return "gpu", f"array on GPU ({name.decode() if isinstance(name, bytes) else name})"
    except admm.GpuUnavailableError as exc:
        return "array-cpu", f"array on numpy (no GPU: {str(exc).split('(')[1].split(')')[0]})"


def per_iteration_ms(case, u0, device, iters, repeats):
    """(min, median) ms per ADMM iteration, the x-step CG iterations per ADMM iteration (array
    backend; None on the CPU path) and the last solve's displacement, of ``repeats`` solves of
    ``iters`` iterations from u0."""
    per, cg = [], None
    for _ in range(repeats):
        r = admm.solve(case, initial=u0, polish=False, lift=False, load_steps=1, max_iter=iters,
                       tol_mm=1e-30, device=device)
        c = r.history["admm_clock_s"]
        per.append(1e3 * (c[-1] - c[2]) / (len(c) - 3))
        if "xstep_cg_iterations" in r.extra:
            cg = r.extra["xstep_cg_iterations"] / r.extra["admm_iterations"]
    return min(per), float(np.median(per)), cg, r.u


def memory_mib(case, u0, device):
    """(host peak MiB of operator setup + 3 iterations incl. SuperLU's untraced factor, GPU
    pool MiB or None)."""
    operators.OPERATOR_CACHE.clear()
    tracemalloc.start()
    admm.solve(case, initial=u0, polish=False, lift=False, load_steps=1, max_iter=3,
               tol_mm=1e-30, device=device)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    ops = admm.prepare(case, factor=device == "cpu")
    untracked = ops.lu.untracked_bytes if device == "cpu" else 0
    gpu = None
    if device == "gpu":
        import cupy

        gpu = cupy.get_default_memory_pool().total_bytes() / 2 ** 20
    return (peak + untracked) / 2 ** 20, gpu


def growth(ns, ts):
    """Least-squares slope of log t against log n (None below two sizes)."""
    if len(ns) < 2:
        return None
    return float(np.polyfit(np.log(ns), np.log(ts), 1)[0])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tets", type=float, nargs="*", default=[1e4, 1e5, 1e6])
    ap.add_argument("--iters", type=int, default=20, help="ADMM iterations per timed solve")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--mesher", choices=("structured", "gmsh"), default="structured")
    ap.add_argument("--agreement", metavar="DATA.npz", default=None,
                    help="first check the array backend against the CPU kernel on the phantom "
                         "(file written by admm_gpu_agreement.py --write)")
    a = ap.parse_args()
    dev, label = array_device()
    cpu = ("compiled C element kernel" if kernel_c.use_kernel()
           else "numpy element loop (no compiled kernel: cffi or a C compiler missing)")
    print(f"[machine] {_load()}; numpy {np.__version__}; CPU path: {cpu}; array backend: "
          f"{label}", flush=True)
    if a.agreement:
        from admm_gpu_agreement import check

        check(a.agreement, dev, label)
    bytes_per_tet = DEFAULT_BYTES_PER_TET
    rows = []
    for target in a.tets:
        need = bytes_per_tet * target
        avail = _available_bytes()
        if need > 0.8 * avail:
            print(f"[skip] ~{target:.0e} tets: about {need / 2 ** 30:.1f} GiB of host memory "
                  f"estimated, {avail / 2 ** 30:.1f} GiB available", flush=True)
            continue
        t = time.perf_counter()
        mesh, how = build_box(target, a.mesher)
        t_mesh = time.perf_counter() - t
        case = box_case(mesh)
        operators.OPERATOR_CACHE.clear()
        u0 = admm.solve(case, polish=False, lift=False, load_steps=1, max_iter=10).u
        setup_cpu = admm.prepare(case).setup_s
        row = {"tets": mesh.n_cells, "vertices": mesh.n_vertices, "mesh_s": t_mesh,
               "setup_s": setup_cpu}
        row["cpu"] = per_iteration_ms(case, u0, "cpu", a.iters, a.repeats)
        row["array"] = per_iteration_ms(case, u0, dev, a.iters, a.repeats)
        row["mem_cpu"] = memory_mib(case, u0, "cpu")
        row["mem_array"] = memory_mib(case, u0, dev)
        bytes_per_tet = max(row["mem_cpu"][0], row["mem_array"][0]) * 2 ** 20 / mesh.n_cells * 1.5
        rows.append(row)
        c, r = row["cpu"], row["array"]
        agree = np.abs(r[3] - c[3]).max() / np.abs(c[3]).max()
        xstep = "AMG-PCG" if admm.prepare(case).device_data[dev].amg is not None else "Jacobi-CG"
        gpu_mem = f", GPU pool {row['mem_array'][1]:.0f} MiB" if row["mem_array"][1] else ""
        print(f"[size] {mesh.n_cells} tets, {mesh.n_vertices} vertices ({how}, meshed in "
              f"{t_mesh:.1f} s, operators {setup_cpu:.2f} s): CPU kernel {c[0]:.2f} "
              f"ms/iteration (median {c[1]:.2f}); "
              f"{label} {r[0]:.2f} ms/iteration (median {r[1]:.2f}, {r[2]:.1f} {xstep} iterations "
              f"per x-step); array / CPU = {r[0] / c[0]:.2f}; their displacements after "
              f"{a.iters} iterations differ by {agree:.1e} (relative); host peak memory CPU "
              f"{row['mem_cpu'][0]:.0f} MiB, array {row['mem_array'][0]:.0f} MiB{gpu_mem}; "
              f"{_load()}", flush=True)
    if rows:
        ns = [r["tets"] for r in rows]
        for key, name in (("cpu", "CPU kernel"), ("array", label)):
            g = growth(ns, [r[key][0] for r in rows])
            print(f"[growth] {name}: time per iteration ~ tets^"
                  f"{'n/a (one size)' if g is None else f'{g:.2f}'} over "
                  f"{', '.join(str(n) for n in ns)} tets", flush=True)
        gm = growth(ns, [r["mem_cpu"][0] for r in rows])
        if gm is not None and math.isfinite(gm):
            print(f"[growth] host peak memory (CPU path) ~ tets^{gm:.2f}", flush=True)
        print("[ratio] array / CPU time per iteration: " + ", ".join(
            f"{r['tets']} tets {r['array'][0] / r['cpu'][0]:.2f}" for r in rows), flush=True)


if __name__ == "__main__":
    main()
