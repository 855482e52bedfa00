"""Render the case-file schema (model/case.schema.json) into docs/case-file.md.

    python tools/schema_doc.py           # write docs/case-file.md
    python tools/schema_doc.py --check   # exit 1 if docs/case-file.md is not up to date
"""
from __future__ import annotations

import sys

from docgen import ROOT, run


def _text():
    from tissue_reference.model.case_doc import case_file_markdown

    return case_file_markdown()


if __name__ == "__main__":
    sys.exit(run(ROOT / "docs" / "case-file.md", _text, "schema_doc.py",
                 __doc__.splitlines()[0]))
