"""Render the command-line reference (the tissue parser) into docs/cli.md.

    python tools/cli_doc.py           # write docs/cli.md
    python tools/cli_doc.py --check   # exit 1 if docs/cli.md is not up to date
"""
from __future__ import annotations

import sys

from docgen import ROOT, run


def _text():
    from tissue_reference.tissue.cli_doc import cli_markdown

    return cli_markdown()


if __name__ == "__main__":
    sys.exit(run(ROOT / "docs" / "cli.md", _text, "cli_doc.py", __doc__.splitlines()[0]))
