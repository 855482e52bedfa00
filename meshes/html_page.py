"""The parts the HTML reports are made of: escaped tables whose headers carry units, key/value
tables of settings (a key's unit suffix, e.g. ``dt_s`` or ``E_kPa``, becomes ``dt (s)``,
``E (kPa)``), images, and the page itself, written whole or not at all.

A cell or a part that is already HTML is wrapped in ``Raw``; anything else is escaped.
"""
from __future__ import annotations

import html
import json
import math
from pathlib import Path

from .io import atomic_path

__all__ = ["STYLE", "Raw", "fmt", "image", "kv_table", "label", "page", "table", "write_page"]

STYLE = ("body{font-family:sans-serif;margin:2em;max-width:72em}"
         "table{border-collapse:collapse;margin:1em 0}"
         "td,th{border:1px solid #999;padding:3px 8px;text-align:right;vertical-align:top}"
         "th{background:#eee}th[scope=row]{text-align:left;font-weight:normal}"
         "td.l{text-align:left}.valid{background:#dfd;padding:.5em 1em;border:2px solid #3a3}"
         ".invalid{background:#fdd;padding:.5em 1em;border:2px solid #c33}"
         ".warn{background:#ffd;padding:.5em 1em;border:1px solid #cc3}"
         "figure{display:inline-block;margin:0 1em 1em 0}")


class Raw(str):
    """Text that is HTML already: put on the page as it is."""


# a key's suffix -> its unit, longest first where one ends another
_SUFFIXES = (("_mm_s2", "mm/s²"), ("_kg_mm3", "kg/mm³"), ("_mm2", "mm²"), ("_kPa", "kPa"),
             ("_mN", "mN"), ("_uJ", "µJ"), ("_ms", "ms"), ("_mm", "mm"), ("_s", "s"),
             ("_deg", "deg"), ("_rel", "relative"), ("_cc", "cm³"))
# keys without a suffix whose unit is known
_KNOWN = {"q": "1/mm²", "r": "1/mm²", "E": "kPa", "itae": "mm·s²", "size": "mm",
          "model_size": "mm", "rho": "kPa", "step_scale": "1"}


def label(key: str) -> str:
    """A JSON key as a table label with its unit: ``max_travel_mm`` -> ``max travel (mm)``."""
    for suffix, unit in _SUFFIXES:
        if key.endswith(suffix) and len(key) > len(suffix):
            return f"{key[:-len(suffix)].replace('_', ' ')} ({unit})"
    if key in _KNOWN:
        return f"{key.replace('_', ' ')} ({_KNOWN[key]})"
    return key.replace("_", " ")


def fmt(v, digits: int = 4) -> str:
    """A value as table text: floats to ``digits`` significant digits, None as an empty cell,
    lists of numbers as ``[a, b, c]``, anything else as JSON."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.{digits}g}" if math.isfinite(v) else str(v)
    if isinstance(v, (int, str)):
        return str(v)
    if isinstance(v, (list, tuple)) and all(isinstance(x, (int, float)) and
                                            not isinstance(x, bool) for x in v):
        return "[" + ", ".join(fmt(float(x), digits) for x in v) + "]"
    return json.dumps(v, default=str)


def _cell(c, tag="td", attrs="") -> str:
    text = c if isinstance(c, Raw) else html.escape(c if isinstance(c, str) else fmt(c))
    return f"<{tag}{attrs}>{text}</{tag}>"


def table(headers, rows, *, caption: str | None = None, row_headers: bool = False) -> Raw:
    """A table: ``headers`` (each naming its unit where it has one), ``rows`` of cells (a
    number is formatted by ``fmt``; ``Raw`` cells are HTML); ``row_headers``: the first cell of
    each row names the row (a quantity with its unit)."""
    cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
    head = "<tr>" + "".join(_cell(h, "th") for h in headers) + "</tr>"
    first = (lambda c: _cell(c, "th", " scope='row'")) if row_headers else _cell
    body = "".join("<tr>" + first(r[0]) + "".join(_cell(c) for c in r[1:]) + "</tr>"
                   for r in rows)
    return Raw(f"<table>{cap}{head}{body}</table>")


def _flat(d: dict, prefix: str = ""):
    for k, v in d.items():
        name = f"{prefix}{label(str(k))}"
        if isinstance(v, dict) and v:
            yield from _flat(v, f"{name}: ")
        else:
            yield name, v


def kv_table(d: dict, *, caption: str | None = None) -> Raw:
    """A dict as a two-column table, one row per key (nested dicts as ``outer: inner`` rows); each
    key is a row header with its unit (``label``)."""
    return table(["setting", "value"], [(k, "none" if v is None else fmt(v))
                                        for k, v in _flat(d)], caption=caption,
                 row_headers=True)


def image(src: str, alt: str, caption: str | None = None, width: int | None = None) -> Raw:
    """A figure with the image at ``src`` (a path relative to the page)."""
    w = f" width='{int(width)}'" if width else ""
    cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
    return Raw(f"<figure><img src='{html.escape(src)}' alt='{html.escape(alt)}'{w}>{cap}"
               "</figure>")


def page(title: str, parts) -> str:
    """A whole HTML page: ``title`` and the body ``parts`` (``Raw`` parts as they are, any other
    text as a paragraph)."""
    body = "\n".join(p if isinstance(p, Raw) else f"<p>{html.escape(str(p))}</p>"
                     for p in parts if p)
    return (f"<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>{html.escape(title)}"
            f"</title><style>{STYLE}</style></head><body>\n{body}\n</body></html>\n")


def write_page(path, text: str) -> Path:
    """Write the page ``text`` to ``path`` whole or not at all."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path
