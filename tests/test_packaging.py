"""One installed top-level name: the layers are ``tissue_reference.<layer>``, so packages of PyPI
called ``control``, ``solvers``, ``meshes``... neither shadow nor overwrite them. Offline: the
wheels are built here (``pip wheel --no-build-isolation``, or written by hand)."""
# namespace_imports: skip
import base64
import hashlib
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NS = "tissue_reference"
LAYERS = ("errors", "meshes", "model", "fem_reference", "solvers", "control", "implant",
          "verification", "tissue")
DATA = ["meshes/cases/phantom.toml", "model/case.schema.json", "solvers/admm_kernel.c",
        "solvers/admm_kernel.h", "tissue/schemas/solve.schema.json",
        "tissue/schemas/common.schema.json"]

# Run in a child: the layers through tissue_reference only, whatever sits first on sys.path.
CHILD = r'''
import importlib, importlib.util, pkgutil, sys
from pathlib import Path
import numpy as np
mode, where = sys.argv[1], Path(sys.argv[2]).resolve()
LAYERS = ("errors", "meshes", "model", "fem_reference", "solvers", "control", "implant",
          "verification", "tissue")
import tissue_reference
if mode == "fakes":   # the fake packages are what a plain "import control" would get
    for name in LAYERS:
        spec = importlib.util.find_spec(name)
        assert spec is not None and Path(spec.origin).resolve().parent.parent == where, \
            (name, spec and spec.origin)
    modules = []
    for layer in LAYERS:
        pkg = importlib.import_module("tissue_reference." + layer)
        modules += [m.name for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + ".")]
    for name in modules:
        if not name.endswith("__main__"):
            importlib.import_module(name)
    assert len(modules) == int(sys.argv[3]), modules  # every module of every layer
else:                 # installed into a --target folder together with another "control"
    import control
    assert control.DUMMY == "python-control stand-in"
    assert Path(tissue_reference.__file__).resolve().parent == where / "tissue_reference"
from tissue_reference.control.mpc import PushOnlyMPC
from tissue_reference.model.case_schema import SCHEMA_PATH, schema_errors
from tissue_reference.solvers.ckernel import SOURCE
from tissue_reference.tissue.output_schema import schema
import tomllib
step = PushOnlyMPC(1, [True, False, False]).step(np.array([[-1.0], [0.0], [0.0]]),
                                                  np.zeros(3), np.array([-1.0, 0.0, 0.0]))
assert step.du[0] > 0, step
case = Path(tissue_reference.meshes.__file__).with_name("cases") / "phantom.toml"
assert schema_errors(tomllib.loads(case.read_text())) == []
assert SCHEMA_PATH.is_file() and SOURCE.is_file() and schema("solve")["type"] == "object"
leaked = sorted(n for n in set(LAYERS) & set(sys.modules) if (mode, n) != ("target", "control"))
assert not leaked, leaked
print("ok", tissue_reference.control.mpc.__file__)
'''


def _child(mode: str, where: Path, cwd: Path, pythonpath: str):
    env = dict(os.environ, PYTHONPATH=pythonpath, PYTHONDONTWRITEBYTECODE="1")
    count = sum(len(list((ROOT / layer).rglob("*.py"))) - 1 for layer in LAYERS)
    return subprocess.run([sys.executable, "-c", CHILD, mode, str(where), str(count)], cwd=cwd,
                          env=env,
                          capture_output=True, text=True, timeout=300, check=False)


def _fake_packages(folder: Path) -> Path:
    for name in LAYERS:
        (folder / name).mkdir(parents=True)
        (folder / name / "__init__.py").write_text(
            f'raise ImportError("the fake top-level {name!r} was imported")\n')
    return folder


# --------------------------------------------------------------------------- shadowing
def test_top_level_packages_of_the_same_names_first_on_the_path_do_not_shadow(tmp_path):
    """Fake ``control``, ``solvers``, ... first on sys.path (the child's working directory):
    every module of the project still imports, none imports a fake, and real calls work."""
    fakes = _fake_packages(tmp_path / "fakes")
    p = _child("fakes", fakes, cwd=fakes, pythonpath=str(ROOT))
    assert p.returncode == 0, p.stderr[-3000:]
    assert p.stdout.startswith("ok "), p.stdout


def test_a_fake_first_on_the_path_is_seen_by_a_top_level_import(tmp_path):
    """The fakes above would be found: the shadowing test can fail."""
    fakes = _fake_packages(tmp_path / "fakes")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.run([sys.executable, "-c", "import control"], cwd=fakes, env=env,
                       capture_output=True, text=True, timeout=60, check=False)
    assert p.returncode == 1 and "the fake top-level 'control' was imported" in p.stderr


# --------------------------------------------------------------------------- the wheel
def _source_copy(folder: Path) -> Path:
    """What the wheel is built from (the repository's files, no build/ left in the checkout)."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.so")
    for name in (*LAYERS, NS):
        shutil.copytree(ROOT / name, folder / name, ignore=ignore)
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        (folder / name).write_bytes((ROOT / name).read_bytes())
    return folder


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    src = _source_copy(tmp_path_factory.mktemp("src"))
    out = tmp_path_factory.mktemp("wheel")
    p = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-index",
                        "--no-build-isolation", "--disable-pip-version-check", "-q", "-w",
                        str(out), str(src)], capture_output=True, text=True, timeout=300,
                       check=False)
    assert p.returncode == 0, p.stderr[-3000:]
    (whl,) = out.glob("tissue_reference-*.whl")
    return whl


def _top_level(names) -> set:
    return {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}


def test_the_wheel_installs_only_tissue_reference_with_every_subpackage_and_its_data(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    assert _top_level(names) == {NS}, sorted(_top_level(names))
    for layer in LAYERS:  # every package folder of the repository is in it
        for init in (ROOT / layer).rglob("__init__.py"):
            assert f"{NS}/{init.relative_to(ROOT).as_posix()}" in names, init
    for path in DATA + ["__init__.py", "__main__.py"]:
        assert f"{NS}/{path}" in names, path
    assert not [n for n in names if n.startswith(f"{NS}/tests/") or "__pycache__" in n]
    (ep,) = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
    assert "tissue = tissue_reference.tissue.cli:main" in zipfile.ZipFile(wheel).read(ep).decode()


INSTALLED = """
import importlib.util, json, sys
from importlib import metadata
import tissue_reference.meshes as m
dist = metadata.distribution("tissue-reference")
print(json.dumps({
    "files": [f.as_posix() for f in dist.files],
    "direct_url": json.loads(dist.read_text("direct_url.json") or "{}"),
    "meshes": m.__file__,
    "top_level": [s.origin for n in sys.argv[1:] if (s := importlib.util.find_spec(n))],
}))
"""


def test_the_installed_distribution_has_no_other_top_level_name(tmp_path):
    """RECORD of the installed distribution (read from outside the repository): tissue_reference,
    its dist-info, the console script and, for an editable install, setuptools' finder and .pth
    (not names of ours). There the layers are not importable at the top level, and an editable
    install imports them from the repository's folders."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    p = subprocess.run([sys.executable, "-c", INSTALLED, *LAYERS], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=120, check=False)
    assert p.returncode == 0, p.stderr[-3000:]
    out = json.loads(p.stdout)
    names = [f for f in out["files"] if not f.startswith("../")]
    assert any(f.endswith(".dist-info/RECORD") for f in names), names
    tops = _top_level(f for f in names if not f.split("/")[-1].startswith("__editable__"))
    assert tops <= {NS}, sorted(tops)
    assert not [f for f in out["top_level"] if f and Path(f).resolve().is_relative_to(ROOT)], out
    if out["direct_url"].get("dir_info", {}).get("editable"):
        assert Path(out["meshes"]).resolve() == ROOT / "meshes" / "__init__.py", out["meshes"]
    else:
        assert f"{NS}/meshes/__init__.py" in names, names


def _dummy_wheel(folder: Path, name: str = "control") -> Path:
    """A wheel of another distribution that installs a top-level ``control`` package."""
    dist = f"{name}-0.0.1.dist-info"
    files = {f"{name}/__init__.py": 'DUMMY = "python-control stand-in"\n',
             f"{name}/mpc.py": "raise ImportError('the other control.mpc')\n",
             f"{dist}/METADATA": f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.0.1\n",
             f"{dist}/WHEEL": "Wheel-Version: 1.0\nGenerator: tests\nRoot-Is-Purelib: true\n"
                              "Tag: py3-none-any\n"}
    record = []
    for path, text in files.items():
        digest = base64.urlsafe_b64encode(hashlib.sha256(text.encode()).digest()).rstrip(b"=")
        record.append(f"{path},sha256={digest.decode()},{len(text.encode())}")
    files[f"{dist}/RECORD"] = "\n".join(record + [f"{dist}/RECORD,,", ""])
    whl = folder / f"{name}-0.0.1-py3-none-any.whl"
    with zipfile.ZipFile(whl, "w") as z:
        for path, text in files.items():
            z.writestr(path, text)
    return whl


def _snapshot(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_another_distribution_with_a_top_level_control_leaves_ours_intact(wheel, tmp_path):
    target = tmp_path / "site"

    def install(whl):
        p = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-index",
                            "--no-compile", "--disable-pip-version-check", "-q", "--target",
                            str(target), str(whl)], capture_output=True, text=True, timeout=300,
                           check=False)
        assert p.returncode == 0, p.stderr[-3000:]

    install(wheel)
    ours = _snapshot(target / NS)
    assert "control/mpc.py" in ours
    install(_dummy_wheel(tmp_path))
    assert (target / "control" / "__init__.py").is_file()
    assert _snapshot(target / NS) == ours
    empty = tmp_path / "elsewhere"
    empty.mkdir()
    p = _child("target", target, cwd=empty, pythonpath=str(target))
    assert p.returncode == 0, p.stderr[-3000:]
    assert p.stdout.strip() == f"ok {target.resolve() / NS / 'control' / 'mpc.py'}", p.stdout


# --------------------------------------------------------------------------- the rewriter
def _rewriter():
    spec = importlib.util.spec_from_file_location("namespace_imports",
                                                  ROOT / "tools" / "namespace_imports.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


BEFORE = '''import logging
import subprocess
import sys

import fem_reference as fr
import meshes.builders
import meshes.io
import solvers
from control.mpc import PushOnlyMPC
from model.case import (
    load_case,
)

log = logging.getLogger("tissue.verify")
GROUP = "tissue.solvers"
SOLVERS = {"admm": "solvers.admm"}


def f(monkeypatch, name):
    """Example::

        from verification.verify import verify
    """
    monkeypatch.setattr("fem_reference.solver.solve", None)
    monkeypatch.setattr(meshes.builders, "x", __import__("model.case").case)
    subprocess.run([sys.executable, "-m", "tissue", "--version"])  # python -m tissue
    return __import__("importlib").import_module(f"tissue.{name}"), fr, solvers, PushOnlyMPC
'''

AFTER = '''import logging
import subprocess
import sys

import tissue_reference.fem_reference as fr
import tissue_reference.meshes.builders
import tissue_reference.meshes.io
meshes = tissue_reference.meshes
from tissue_reference import solvers
from tissue_reference.control.mpc import PushOnlyMPC
from tissue_reference.model.case import (
    load_case,
)

log = logging.getLogger("tissue.verify")
GROUP = "tissue.solvers"
SOLVERS = {"admm": "tissue_reference.solvers.admm"}


def f(monkeypatch, name):
    """Example::

        from tissue_reference.verification.verify import verify
    """
    monkeypatch.setattr("tissue_reference.fem_reference.solver.solve", None)
    monkeypatch.setattr(meshes.builders, "x", __import__("tissue_reference.model.case").model.case)
    subprocess.run([sys.executable, "-m", "tissue_reference", "--version"])  # python -m tissue_reference
    return __import__("importlib").import_module(f"tissue_reference.tissue.{name}"), fr, solvers, PushOnlyMPC
'''


def test_the_rewriter_moves_imports_strings_and_commands_under_the_package():
    tool = _rewriter()
    assert tool.rewrite_python(BEFORE) == AFTER
    assert tool.rewrite_python(AFTER) == AFTER


def test_the_rewriter_leaves_markdown_prose_and_runs_once():
    tool = _rewriter()
    md = ("Run `python -m tissue solve` or `tissue solve`; `fem_reference.estimate`, the group "
          "`tissue.solvers`, `meshes/cases/phantom.toml`.\n\n```python\nimport fem_reference as "
          "fr\nfrom model.case import load_case\n```\n")
    once = tool.rewrite_markdown(md)
    assert once == ("Run `python -m tissue_reference solve` or `tissue solve`; "
                    "`tissue_reference.fem_reference.estimate`, the group `tissue.solvers`, "
                    "`meshes/cases/phantom.toml`.\n\n```python\nimport "
                    "tissue_reference.fem_reference as fr\nfrom tissue_reference.model.case "
                    "import load_case\n```\n")
    assert tool.rewrite_markdown(once) == once


def test_nothing_in_the_tree_still_names_a_layer_at_the_top_level():
    """The rewriter has nothing left to do (run it after a merge that brings old imports)."""
    tool = _rewriter()
    left = [str(p.relative_to(ROOT)) for p in tool.tracked_files(ROOT)
            if len(set(tool.rewrite_file(p)[:2])) > 1]
    assert left == [], f"run: python tools/namespace_imports.py  ({left})"
