"""3D pictures for the reports: the deformed tissue coloured by a vertex field.

``render`` draws the boundary of a tetrahedral mesh moved by a displacement (mm) and coloured by
a scalar per vertex, as a PNG written whole or not at all (a triangle mesh in 2D: the deformed
triangles themselves, with matplotlib). It renders with pyvista off screen in
a child process (a crashed or hanging OpenGL context cannot take the report down with it) and
falls back to matplotlib's 3D polygons where no GL is available; ``method`` in the result says
which one drew the picture.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from tissue_reference.meshes.io import atomic_path, save_figure

__all__ = ["boundary_faces", "render"]

PYVISTA_TIMEOUT_S = 120

_PYVISTA_SCRIPT = r"""
import sys
import numpy as np
import pyvista as pv
d = np.load(sys.argv[1])
X = d["points"] + d["u"]
cells = d["cells"]
grid = pv.UnstructuredGrid(np.hstack([np.full((len(cells), 1), 4), cells]).ravel(),
                           np.full(len(cells), pv.CellType.TETRA), X)
grid.point_data[sys.argv[4]] = d["scalar"]
p = pv.Plotter(off_screen=True, window_size=(900, 700))
p.add_mesh(grid, scalars=sys.argv[4], cmap="viridis", show_edges=False,
           scalar_bar_args={"title": sys.argv[4] + "\n", "vertical": True,
                            "position_x": 0.86, "position_y": 0.15, "height": 0.7,
                            "width": 0.06, "title_font_size": 14, "label_font_size": 12,
                            "fmt": "%.3g", "n_labels": 5})
ref = pv.UnstructuredGrid(np.hstack([np.full((len(cells), 1), 4), cells]).ravel(),
                          np.full(len(cells), pv.CellType.TETRA), d["points"])
p.add_mesh(ref.extract_feature_edges(), color="grey", opacity=0.3)
p.add_text(sys.argv[3], font_size=10)
p.camera_position = "iso"
p.screenshot(sys.argv[2])
"""


def boundary_faces(cells: np.ndarray) -> np.ndarray:
    """The triangles (k, 3) that belong to one tetrahedron only."""
    faces = np.concatenate([cells[:, [0, 1, 2]], cells[:, [0, 1, 3]], cells[:, [0, 2, 3]],
                            cells[:, [1, 2, 3]]])
    key = np.sort(faces, axis=1)
    _, idx, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    return faces[idx[counts == 1]]


def _matplotlib(points, cells, u, scalar, path, title, label):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    X = points + u
    tri = boundary_faces(cells)
    val = scalar[tri].mean(axis=1)
    norm = plt.Normalize(float(val.min()), float(val.max()) or 1.0)
    fig = plt.figure(figsize=(7.5, 6))
    ax = fig.add_subplot(projection="3d")
    ax.add_collection3d(Poly3DCollection(X[tri], facecolors=plt.cm.viridis(norm(val)),
                                         edgecolors="none"))
    lo, hi = X.min(axis=0), X.max(axis=0)
    for set_lim, a, b in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), lo, hi):
        set_lim(a, b)
    ax.set_box_aspect(hi - lo)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.set_title(title, fontsize=9)
    sm = plt.cm.ScalarMappable(norm=norm, cmap="viridis")
    fig.colorbar(sm, ax=ax, shrink=0.6, label=label)
    save_figure(fig, path)


def _matplotlib_2d(points, cells, u, scalar, path, title, label):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    X = points + u
    fig, ax = plt.subplots(figsize=(7.5, 5))
    art = ax.tripcolor(X[:, 0], X[:, 1], cells[:, :3], scalar, shading="gouraud",
                       cmap="viridis")
    ax.triplot(points[:, 0], points[:, 1], cells[:, :3], color="0.6", lw=0.2, alpha=0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(title, fontsize=9)
    fig.colorbar(art, ax=ax, shrink=0.8, label=label)
    save_figure(fig, path)


def render(mesh, u, scalar, path, *, title: str = "", label: str = "value",
           use_pyvista: bool = True) -> dict:
    """Draw ``mesh`` (MeshData, tetrahedra) moved by ``u`` ((n, 3) mm) and coloured by
    ``scalar`` ((n,)) into the PNG ``path``. Returns {"path", "method": "pyvista" |
    "matplotlib", "why" (the reason pyvista was not used, if it was not)}."""
    path = Path(path)
    points = np.asarray(mesh.points, float)
    cells = np.asarray(mesh.cells, np.int64)
    u = np.asarray(u, float).reshape(points.shape)
    scalar = np.asarray(scalar, float).reshape(-1)
    why = None
    if points.shape[1] == 2:
        _matplotlib_2d(points, cells, u, scalar, path, title, label)
        return {"path": str(path), "method": "matplotlib", "why": "a 2D mesh"}
    if use_pyvista and points.shape[1] == 3:
        with tempfile.TemporaryDirectory() as d:
            npz, png = Path(d) / "view.npz", Path(d) / "view.png"
            np.savez(npz, points=points, cells=cells, u=u, scalar=scalar)
            env = {**os.environ, "PYVISTA_OFF_SCREEN": "true"}
            try:
                run = subprocess.run([sys.executable, "-c", _PYVISTA_SCRIPT, str(npz), str(png),
                                      title, label], capture_output=True, text=True, env=env,
                                     check=False,
                                     timeout=PYVISTA_TIMEOUT_S)
                if run.returncode == 0 and png.is_file() and png.stat().st_size > 0:
                    with atomic_path(path) as tmp:
                        tmp.write_bytes(png.read_bytes())
                    return {"path": str(path), "method": "pyvista"}
                why = (run.stderr.strip().splitlines() or [f"exit {run.returncode}"])[-1]
            except (OSError, subprocess.TimeoutExpired) as exc:
                why = f"{type(exc).__name__}: {exc}"
    _matplotlib(points, cells, u, scalar, path, title, label)
    return {"path": str(path), "method": "matplotlib", "why": why}
