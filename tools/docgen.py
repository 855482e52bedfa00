"""Shared driver of the documentation generators: write a generated page, or check it is
current (exit 1 if not)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(doc: Path, make_text, script: str, description: str, argv=None) -> int:
    """Write ``doc`` from ``make_text()`` (imported with the repository on sys.path), or with
    --check only compare."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--check", action="store_true", help="only compare, write nothing")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    text = make_text()
    if args.check:
        same = doc.is_file() and doc.read_text(encoding="utf-8") == text
        print(f"{doc}: {'up to date' if same else f'out of date, run tools/{script}'}")
        return 0 if same else 1
    doc.write_text(text, encoding="utf-8")
    print(f"wrote {doc}")
    return 0
