"""The README's Python runs as a newcomer would run it: copied into a folder outside the
repository. Every answer it computes is valid and within the loads where answers converge (its
warnings would say what is wrong)."""
import json
import subprocess
import sys
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"

PRELUDE = """
import atexit, json, warnings
caught = []
warnings.simplefilter("always")
warnings.showwarning = lambda message, category, *a, **k: caught.append(
    [category.__name__, str(message)])
atexit.register(lambda: print("WARNINGS=" + json.dumps(caught)))
"""


def python_block(heading: str) -> str:
    text = README.read_text()
    part = text[text.index(heading):]
    start = part.index("```python\n") + len("```python\n")
    return part[start:part.index("```", start)]


def test_the_readme_python_runs_from_another_folder(tmp_path):
    code = python_block("## Python in 20 lines")
    assert 'load_case("phantom-indenter' in code
    p = subprocess.run([sys.executable, "-c", PRELUDE + code], cwd=tmp_path, capture_output=True,
                       text=True, timeout=600, check=False)
    assert p.returncode == 0, p.stderr[-3000:]
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("WARNINGS=")][-1]
    caught = json.loads(line[len("WARNINGS="):])
    concerns = [m for c, m in caught if c == "TissueWarning"]
    assert not [m for m in concerns if m.startswith("the answer is not valid")], concerns
    assert not [m for m in concerns if "no mesh-converged answer is known" in m
                or "radius: past" in m], concerns
