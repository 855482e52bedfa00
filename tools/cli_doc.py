"""Render the command-line reference (the tissue parser) into docs/cli.md.

    python tools/cli_doc.py           # write docs/cli.md
    python tools/cli_doc.py --check   # exit 1 if docs/cli.md is not up to date
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "cli.md"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only compare, write nothing")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from tissue.cli_doc import cli_markdown

    text = cli_markdown()
    if args.check:
        same = DOC.is_file() and DOC.read_text(encoding="utf-8") == text
        print(f"{DOC}: {'up to date' if same else 'out of date, run tools/cli_doc.py'}")
        return 0 if same else 1
    DOC.write_text(text, encoding="utf-8")
    print(f"wrote {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
