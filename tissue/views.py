"""3D pictures for the reports: the deformed tissue coloured by a vertex field.

``render`` draws the boundary of a tetrahedral mesh moved by a displacement (mm) and coloured by
a scalar per vertex, as a PNG written whole or not at all (a triangle mesh in 2D: the deformed
triangles themselves, with matplotlib). It renders with pyvista off screen in
a child process (a crashed or hanging OpenGL context cannot take the report down with it) and
falls back to matplotlib's 3D polygons where no GL is available; ``method`` in the result says
which one drew the picture. ``start_views`` draws several pictures of one deformed mesh in one
child process (pyvista's import, about a second, paid once) while the caller goes on with other
work; ``PendingViews.wait`` collects them.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from tissue_reference.meshes.io import atomic_path, save_figure

__all__ = ["PendingViews", "boundary_faces", "render", "start_views"]

PYVISTA_TIMEOUT_S = 120

_PYVISTA_SCRIPT = r"""
import json
import sys
import numpy as np
import pyvista as pv
d = np.load(sys.argv[1])
views = json.loads(sys.argv[2])
X = d["points"] + d["u"]
cells = d["cells"]
topology = np.hstack([np.full((len(cells), 1), 4), cells]).ravel()
kinds = np.full(len(cells), pv.CellType.TETRA)
edges = pv.UnstructuredGrid(topology, kinds, d["points"]).extract_feature_edges()
for k, (png, title, label) in enumerate(views):
    grid = pv.UnstructuredGrid(topology, kinds, X)
    grid.point_data[label] = d["scalars"][k]
    p = pv.Plotter(off_screen=True, window_size=(900, 700))
    p.add_mesh(grid, scalars=label, cmap="viridis", show_edges=False,
               scalar_bar_args={"title": label + "\n", "vertical": True,
                                "position_x": 0.86, "position_y": 0.15, "height": 0.7,
                                "width": 0.06, "title_font_size": 14, "label_font_size": 12,
                                "fmt": "%.3g", "n_labels": 5})
    p.add_mesh(edges, color="grey", opacity=0.3)
    p.add_text(title, font_size=10)
    p.camera_position = "iso"
    p.screenshot(png)
    p.close()
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


class PendingViews:
    """Pictures being drawn by a child process (``start_views``); ``wait`` returns one result
    per view, as ``render`` does, each drawn by pyvista or, where it failed, by matplotlib."""

    def __init__(self, points, cells, u, views, proc=None, tmp=None, why=None):
        self._args = (points, cells, u)
        self._views = views
        self._proc, self._tmp, self._why = proc, tmp, why

    @staticmethod
    def png(folder: str, k: int) -> Path:
        """Where the child process writes view ``k`` in its temporary ``folder``."""
        return Path(folder) / f"view{k}.png"

    def wait(self) -> list[dict]:
        points, cells, u = self._args
        why = self._why
        if self._proc is not None:
            try:
                _, err = self._proc.communicate(timeout=PYVISTA_TIMEOUT_S)
                if self._proc.returncode != 0:
                    why = (err.strip().splitlines() or [f"exit {self._proc.returncode}"])[-1]
            except subprocess.TimeoutExpired as exc:
                self._proc.kill()
                self._proc.communicate()
                why = f"{type(exc).__name__}: {exc}"
        try:
            return self._collect(points, cells, u, why)
        finally:
            if self._tmp is not None:
                self._tmp.cleanup()
                self._tmp = None

    def _collect(self, points, cells, u, why) -> list[dict]:
        out = []
        for k, v in enumerate(self._views):
            png = self.png(self._tmp.name, k) if self._tmp is not None else None
            if self._proc is not None and why is None and png.is_file() \
                    and png.stat().st_size > 0:
                with atomic_path(v["path"]) as tmp:
                    tmp.write_bytes(png.read_bytes())
                out.append({"path": str(v["path"]), "method": "pyvista"})
                continue
            if points.shape[1] == 2:
                _matplotlib_2d(points, cells, u, v["scalar"], v["path"], v["title"], v["label"])
                out.append({"path": str(v["path"]), "method": "matplotlib", "why": "a 2D mesh"})
                continue
            _matplotlib(points, cells, u, v["scalar"], v["path"], v["title"], v["label"])
            out.append({"path": str(v["path"]), "method": "matplotlib",
                        "why": why or "no picture from pyvista"})
        return out


def start_views(mesh, u, views, *, use_pyvista: bool = True) -> PendingViews:
    """Start drawing ``mesh`` (MeshData) moved by ``u`` ((n, dim) mm) once per view, each a
    dict with ``scalar`` ((n,) per vertex), ``path`` (the PNG), ``title`` and ``label``; a 3D
    mesh in one pyvista child process that runs while the caller goes on."""
    points = np.asarray(mesh.points, float)
    cells = np.asarray(mesh.cells, np.int64)
    u = np.asarray(u, float).reshape(points.shape)
    views = [{**v, "path": Path(v["path"]), "title": str(v.get("title", "")),
              "label": str(v.get("label", "value")),
              "scalar": np.asarray(v["scalar"], float).reshape(-1)} for v in views]
    if not (use_pyvista and points.shape[1] == 3 and views):
        why = None if use_pyvista else "pyvista not asked for"
        return PendingViews(points, cells, u, views, why=why)
    tmp = tempfile.TemporaryDirectory()
    npz = Path(tmp.name) / "views.npz"
    np.savez(npz, points=points, cells=cells, u=u,
             scalars=np.stack([v["scalar"] for v in views]))
    spec = [(str(PendingViews.png(tmp.name, k)), v["title"], v["label"])
            for k, v in enumerate(views)]
    env = {**os.environ, "PYVISTA_OFF_SCREEN": "true"}
    try:
        proc = subprocess.Popen([sys.executable, "-c", _PYVISTA_SCRIPT, str(npz),
                                 json.dumps(spec)], stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True, env=env)
    except OSError as exc:
        return PendingViews(points, cells, u, views, tmp=tmp,
                            why=f"{type(exc).__name__}: {exc}")
    return PendingViews(points, cells, u, views, proc=proc, tmp=tmp)


def render(mesh, u, scalar, path, *, title: str = "", label: str = "value",
           use_pyvista: bool = True) -> dict:
    """Draw ``mesh`` (MeshData, tetrahedra) moved by ``u`` ((n, 3) mm) and coloured by
    ``scalar`` ((n,)) into the PNG ``path``. Returns {"path", "method": "pyvista" |
    "matplotlib", "why" (the reason pyvista was not used, if it was not)}."""
    view = {"scalar": scalar, "path": path, "title": title, "label": label}
    return start_views(mesh, u, [view], use_pyvista=use_pyvista).wait()[0]
