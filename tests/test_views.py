"""3D report pictures: the boundary of a tet mesh, drawn with pyvista off screen or matplotlib."""
import numpy as np

from tissue_reference.meshes.builders import box
from tissue_reference.tissue.views import boundary_faces, render


def test_boundary_faces_are_the_faces_of_one_cell_only():
    one = np.array([[0, 1, 2, 3]])
    assert len(boundary_faces(one)) == 4
    two = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])      # sharing the face (1, 2, 3)
    faces = {tuple(sorted(f)) for f in boundary_faces(two)}
    assert len(faces) == 6 and (1, 2, 3) not in faces


def test_render_writes_a_png_either_way(tmp_path):
    m = box(5.0)
    u = 0.1 * m.points
    for use in (True, False):
        out = render(m, u, np.linalg.norm(u, axis=1), tmp_path / f"v{use}.png", title="t",
                     label="|u| (mm)", use_pyvista=use)
        data = (tmp_path / f"v{use}.png").read_bytes()
        assert data[:4] == b"\x89PNG" and len(data) > 5000
        assert out["method"] in (("pyvista", "matplotlib") if use else ("matplotlib",))
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_a_2d_mesh_is_drawn_as_its_deformed_triangles(tmp_path):
    from tissue_reference.meshes.builders_blocks import rectangle

    m = rectangle(2.5)
    u = np.zeros_like(m.points)
    u[:, 0] = 0.05 * m.points[:, 1]
    out = render(m, u, np.linalg.norm(u, axis=1), tmp_path / "flat.png", label="|u| (mm)")
    data = (tmp_path / "flat.png").read_bytes()
    assert data[:4] == b"\x89PNG" and out["method"] == "matplotlib" and out["why"] == "a 2D mesh"


def test_several_views_of_one_state_come_from_one_child_process(tmp_path, monkeypatch):
    import subprocess

    from tissue_reference.tissue import views

    started = []
    real = subprocess.Popen

    def counted(*a, **k):
        started.append(a[0])
        return real(*a, **k)

    monkeypatch.setattr(views.subprocess, "Popen", counted)
    m = box(5.0)
    u = 0.1 * m.points
    pending = views.start_views(m, u, [
        {"scalar": np.linalg.norm(u, axis=1), "path": tmp_path / "a.png", "label": "|u| (mm)"},
        {"scalar": m.points[:, 2], "path": tmp_path / "b.png", "label": "z (mm)"}])
    out = pending.wait()
    assert len(started) == 1
    assert [o["path"] for o in out] == [str(tmp_path / "a.png"), str(tmp_path / "b.png")]
    a, b = (tmp_path / "a.png").read_bytes(), (tmp_path / "b.png").read_bytes()
    assert a[:4] == b[:4] == b"\x89PNG" and a != b
