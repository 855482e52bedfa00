"""Builtin meshes are kept on disk and read back instead of meshed again: the same arrays and
regions, a file per builder and sizes, a stand-in builder never cached, a damaged file rebuilt,
and the cache can be turned off."""
import numpy as np
import pytest

from tissue_reference.meshes import builders, mesh_cache


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("TISSUE_MESH_CACHE", str(tmp_path))
    return tmp_path


def _same(a, b):
    assert np.array_equal(a.points, b.points) and np.array_equal(a.cells, b.cells)
    for kind in ("facet_regions", "point_regions", "cell_regions"):
        ra, rb = getattr(a, kind), getattr(b, kind)
        assert set(ra) == set(rb)
        assert all(np.array_equal(ra[k], rb[k]) for k in ra)
    assert (a.curved_edges is None) == (b.curved_edges is None)
    if a.curved_edges is not None:
        assert np.array_equal(a.curved_edges, b.curved_edges)
        assert np.array_equal(a.curved_points, b.curved_points)


def test_a_mesh_is_read_back_whole(cache, monkeypatch):
    reads = []
    real = mesh_cache.read_cached
    monkeypatch.setattr(mesh_cache, "read_cached", lambda p: reads.append(p) or real(p))
    first = builders.build("phantom", 14.0)
    assert len(list(cache.glob("phantom-*.npz"))) == 1 and reads == []
    again = builders.build("phantom", 14.0)
    assert len(reads) == 1
    _same(first, again)
    assert first.curved_edges is not None and first.point_regions
    builders.build("phantom", 16.0)
    assert len(list(cache.glob("phantom-*.npz"))) == 2


def test_a_stand_in_builder_is_not_cached(cache, monkeypatch):
    box = builders.BUILDERS["box"]
    monkeypatch.setitem(builders.BUILDERS, "box", lambda size, out=None: box(10.0, out=out))
    builders.build("box", 4.0)
    assert list(cache.glob("*.npz")) == []


def test_a_damaged_file_is_built_again(cache):
    first = builders.build("box", 5.0)
    (path,) = cache.glob("box-*.npz")
    path.write_bytes(b"not an npz file")
    _same(first, builders.build("box", 5.0))
    _same(first, mesh_cache.read_cached(path))


def test_the_cache_can_be_turned_off(tmp_path, monkeypatch):
    monkeypatch.setenv("TISSUE_MESH_CACHE", "off")
    builders.build("box", 5.0)
    assert mesh_cache.cache_dir() is None and list(tmp_path.glob("**/*.npz")) == []


def test_the_command_line_says_when_gmsh_meshed_and_the_next_run_reads_the_cache(cache,
                                                                                 monkeypatch,
                                                                                 capsys):
    from tissue_reference.tissue import common
    from tissue_reference.tissue.cli import main

    monkeypatch.setattr(common, "ANNOUNCE_LOAD_S", 0.0)   # say it however fast gmsh was
    argv = ["solve", "phantom", "--size", "15", "--push", "A1=1", "--no-estimate"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "meshed 'phantom' at size 15 mm with gmsh" in err
    assert "later runs read it from the mesh cache" in err
    built = mesh_cache.builds()
    assert main(argv + ["-v"]) == 0
    err = capsys.readouterr().err
    assert "with gmsh" not in err and "read from the cache" in err   # -v: where it came from
    assert mesh_cache.builds() == built
