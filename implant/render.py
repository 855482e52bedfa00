"""Colour map of a per-vertex distance (mm) on the skin, rendered off-screen to PNG, and the field
written to VTU. pyvista (VTK) off-screen first; on a machine where VTK cannot open an off-screen
context (no display, no OSMesa/EGL) a matplotlib 3D trisurf PNG is written instead and the
returned backend says so. The VTK render runs in a child process: VTK's OpenGL set-up can abort
the whole process (not raise) when other native libraries (PETSc, dolfinx) are loaded, so a
crash there only costs the fallback.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

import tissue_reference
from tissue_reference.errors import WriteError
from tissue_reference.meshes.io import atomic_path, save_figure

__all__ = ["render_distance_png", "write_surface_vtu"]


def write_surface_vtu(points, triangles, path, *, point_data=None) -> Path:
    """A triangle surface with vertex fields (e.g. ``distance_mm``) as VTU, whole or not at all."""
    import meshio

    path = Path(path)
    m = meshio.Mesh(np.asarray(points, float), [("triangle", np.asarray(triangles))],
                    point_data={k: np.asarray(v, float) for k, v in (point_data or {}).items()})
    try:
        with atomic_path(path, suffix=".vtu") as tmp:
            meshio.write(str(tmp), m, file_format="vtu")
    except OSError as exc:
        raise WriteError(f"cannot write {str(path)!r}: {exc}") from exc
    return path


def _pyvista_png(points, triangles, values, path, title, clim):
    import pyvista as pv

    pv.OFF_SCREEN = True
    faces = np.column_stack([np.full(len(triangles), 3), triangles]).ravel()
    mesh = pv.PolyData(np.asarray(points, float), faces)
    mesh.point_data[title] = np.asarray(values, float)
    pl = pv.Plotter(off_screen=True, window_size=(900, 700))
    pl.add_mesh(mesh, scalars=title, cmap="viridis", clim=clim, show_edges=False,
                scalar_bar_args={"title": title})
    pl.view_vector((0.3, -0.4, 1.0), viewup=(0, 1, 0))
    with atomic_path(path, suffix=".png") as tmp:
        pl.screenshot(str(tmp))
    pl.close()


def _matplotlib_png(points, triangles, values, path, title, clim):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = np.asarray(points, float)
    fig = plt.figure(figsize=(9, 7))
    ax = fig.add_subplot(projection="3d")
    fc = np.asarray(values, float)[np.asarray(triangles)].mean(axis=1)
    surf = ax.plot_trisurf(p[:, 0], p[:, 1], p[:, 2], triangles=triangles, cmap="viridis",
                           linewidth=0)
    surf.set_array(fc)
    surf.set_clim(*clim)
    fig.colorbar(surf, ax=ax, label=title)
    ax.view_init(elev=60, azim=-90)
    save_figure(fig, path)


def render_distance_png(points, triangles, values, path, *, title: str = "distance (mm)",
                        clim=None) -> str:
    """Render the field ``values`` on the surface to ``path`` (PNG). Returns the backend used:
    'pyvista' or 'matplotlib (pyvista off-screen failed: ...)'."""
    vals = np.asarray(values, float)
    clim = clim or (0.0, max(float(vals.max()), 1e-9))
    path = Path(path).resolve()   # the child runs in another folder
    import subprocess
    import sys
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        npz = Path(d) / "field.npz"
        np.savez(npz, points=np.asarray(points, float), triangles=np.asarray(triangles),
                 values=vals, clim=np.asarray(clim, float), title=np.asarray(title))
        try:
            child = [sys.executable, "-m", "tissue_reference.implant.render", str(npz), str(path)]
            # run from the folder that holds the package (site-packages, or the repository)
            r = subprocess.run(child, capture_output=True, text=True, timeout=120, check=False,
                               cwd=str(Path(tissue_reference.__file__).resolve().parents[1]))
            if r.returncode == 0:
                return "pyvista"
            tail = (r.stderr.strip().splitlines() or ["?"])[-1]
            reason = f"child exited with {r.returncode}: {tail}"[:200]
        except subprocess.TimeoutExpired:
            reason = "child timed out"
    try:
        _matplotlib_png(points, triangles, vals, path, title, clim)
    except Exception as exc:
        raise WriteError(f"cannot render {str(path)!r}: pyvista failed ({reason}); matplotlib "
                         f"failed ({exc})") from exc
    return f"matplotlib (pyvista off-screen failed: {reason})"


def _main(argv) -> int:
    z = np.load(argv[0])
    _pyvista_png(z["points"], z["triangles"], z["values"], argv[1], str(z["title"]),
                 tuple(z["clim"].tolist()))
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(_main(sys.argv[1:]))
