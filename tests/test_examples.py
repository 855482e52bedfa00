"""Every script in examples/ runs as a user runs it (``python examples/NAME.py`` from the
repository's root, in a process of its own), exits with status 0 and prints its result: each
script's key line is a regular expression its output must match. A script added to examples/
without a key line here fails ``test_every_example_script_has_a_key_line``."""
import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"

# modules a user imports or names as a plugin, not scripts to run (tests/test_verify_fields.py
# and tests/test_tutorial_commands.py use linear_plugin.py)
MODULES = {"linear_plugin.py"}

KEY_LINES = {
    "solve_with_error_bar.py": r"exact \(radial ODE\) 0\.65383 mm: true error 0\.00\d+ mm",
    "verify_a_plugin.py": r"law difference \(not solver error\): 0\.0\d+ mm",
    "convergence_study.py": r"asymptotic: True .*\nextrapolated 0\.6538\d+ mm \+- ",
    "control_jacobian.py": r"column A1 against central differences .*: max relative difference "
                           r"\d\.\de-(0[5-9]|1\d)",
    "mpc_loop.py": r"closed loop: final error \d\.\de-0[3-9] mm",
    "implant_pipeline.py": r"Mass Tensor: converged True",
    "score_a_field.py": r"matched by: interpolated reference",
    "your_own_law.py": r"scored against the stable-neo-hookean reference",
}


def _scripts():
    return sorted(p.name for p in EXAMPLES.glob("*.py") if p.name not in MODULES)


def test_every_example_script_has_a_key_line():
    assert _scripts() == sorted(KEY_LINES)


@pytest.mark.parametrize("name", _scripts())
def test_an_example_says_how_to_run_it_and_runs_main(name):
    """A module docstring with its command line, a ``main()`` and the ``__main__`` guard."""
    tree = ast.parse((EXAMPLES / name).read_text())
    assert f".venv/bin/python examples/{name}" in (ast.get_docstring(tree) or "")
    assert any(isinstance(n, ast.FunctionDef) and n.name == "main" for n in tree.body)
    assert any(isinstance(n, ast.If) and "__main__" in ast.unparse(n.test) for n in tree.body)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(KEY_LINES))
def test_an_example_runs_and_prints_its_result(name):
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    run = subprocess.run([sys.executable, str(EXAMPLES / name)], cwd=ROOT, env=env, check=False,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, (run.stdout + run.stderr)[-4000:]
    assert re.search(KEY_LINES[name], run.stdout), run.stdout[-4000:]
