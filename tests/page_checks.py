"""Checks of an HTML report page with Python's html.parser: the tags balance, every image is a
PNG (a file beside the page or a data: URI), every relative link exists, and every table header
(column or row) that names a physical quantity over numbers carries its unit in parentheses."""
from __future__ import annotations

import base64
import re
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import urlparse

VOID = {"area", "base", "br", "col", "embed", "hr", "img", "input", "link", "meta", "source",
        "track", "wbr"}
# header words that name a quantity with a unit
QUANTITY = re.compile(
    r"displacement|\berror\b|force|reaction|\bpush|\btime\b|itae|\bsse\b|retraction|travel|"
    r"noise|gravity|density|energy|pressure|stress|\barea\b|penetration|\bsize\b|position|"
    r"(^|: )E$|^[uF]_[xyz]\b|\|[uF]\||\bgoal\b|\bdt\b|\bpoint\b", re.IGNORECASE)
UNITS = {"mm", "mN", "kPa", "s", "ms", "µJ", "sqrt uJ", "mm·s²", "1/mm²", "mm/s²", "kg/mm³",
         "mm²", "mm/mm", "%", "rel", "relative", "deg", "cm³"}
UNIT = re.compile(r"\(([^()]*)\)")
NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


class PageError(AssertionError):
    pass


class _Parser(HTMLParser):
    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.stack, self.errors, self.images, self.links = [], [], [], []
        self.tables, self.title = [], None
        self._cell = None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.images.append(a.get("src"))
        if tag == "a" and a.get("href"):
            self.links.append(a["href"])
        if tag == "table":
            self.tables.append([])
        elif tag == "tr" and self.tables:
            self.tables[-1].append([])
        elif tag in ("td", "th") and self.tables and self.tables[-1]:
            self._cell = [tag, "", a.get("scope")]
            self.tables[-1][-1].append(self._cell)
        if tag not in VOID:
            self.stack.append((tag, self.getpos()))

    def handle_startendtag(self, tag, attrs):
        self.handle_starttag(tag, attrs)
        if tag not in VOID:
            self.stack.pop()

    def handle_endtag(self, tag):
        if tag in VOID:
            return
        if not self.stack or self.stack[-1][0] != tag:
            opened = self.stack[-1] if self.stack else None
            self.errors.append(f"</{tag}> at line {self.getpos()[0]} closes {opened}")
            return
        self.stack.pop()
        if tag in ("td", "th"):
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell[1] += data
        if self.stack and self.stack[-1][0] == "title":
            self.title = (self.title or "") + data


def _has_unit(text: str) -> bool:
    return any(g.strip() in UNITS or g.strip().startswith("count")
               for g in UNIT.findall(text))


def _headers_without_units(tables) -> list[str]:
    bad = []
    for rows in tables:
        if not rows:
            continue
        head = rows[0] if all(c[0] == "th" for c in rows[0]) else []
        for j, (_, text, _) in enumerate(head):
            numbers = any(len(r) > j and r[j][0] == "td" and NUMBER.search(r[j][1])
                          for r in rows[1:])
            if numbers and QUANTITY.search(text) and not _has_unit(text):
                bad.append(text.strip())
        for r in rows[1:]:
            if r and r[0][0] == "th" and r[0][2] == "row":
                numbers = any(c[0] == "td" and NUMBER.search(c[1]) for c in r[1:])
                if numbers and QUANTITY.search(r[0][1]) and not _has_unit(r[0][1]):
                    bad.append(r[0][1].strip())
    return bad


def check_page(path) -> dict:
    """Parse the page at ``path``; raise PageError naming what is wrong. Returns what was found:
    {"images": [src], "links": [href], "tables": number of tables, "title": str}."""
    path = Path(path)
    p = _Parser()
    p.feed(path.read_text(encoding="utf-8"))
    p.close()
    errors = list(p.errors)
    errors += [f"<{t}> opened at line {pos[0]} is never closed" for t, pos in p.stack]
    if not p.title or not p.title.strip():
        errors.append("no <title>")
    for src in p.images:
        if not src:
            errors.append("an <img> without src")
        elif src.startswith("data:"):
            head, _, data = src.partition(",")
            if head != "data:image/png;base64" or \
                    base64.b64decode(data)[:8] != b"\x89PNG\r\n\x1a\n":
                errors.append(f"<img> data URI {head!r} is not a base64 PNG")
        else:
            f = path.parent / src
            if not f.is_file():
                errors.append(f"<img src={src!r}>: no such file beside the page")
            elif f.read_bytes()[:8] != b"\x89PNG\r\n\x1a\n":
                errors.append(f"<img src={src!r}>: not a PNG")
    for href in p.links:
        u = urlparse(href)
        if not u.scheme and not href.startswith("#") and not (path.parent / u.path).exists():
            errors.append(f"<a href={href!r}>: no such file")
    bad = _headers_without_units(p.tables)
    if bad:
        errors.append(f"table headers of numbers without a unit: {bad}")
    if errors:
        raise PageError(f"{path}: " + "; ".join(errors))
    return {"images": p.images, "links": p.links, "tables": len(p.tables), "title": p.title}
