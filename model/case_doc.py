"""The case-file reference in Markdown, rendered from the schema (``case.schema.json``), so that the
document and the loader never disagree. ``tools/schema_doc.py`` writes it to docs/case-file.md."""
from __future__ import annotations

from .case_schema import case_schema, expected, is_table, resolve_ref, show

__all__ = ["case_file_markdown"]

HEADER = "<!-- generated from model/case.schema.json by tools/schema_doc.py; do not edit -->"


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _branches(table: dict) -> list[tuple]:
    """(type, then-schema) of each if/then branch of a table."""
    out = []
    for b in table.get("allOf", ()):
        const = b.get("if", {}).get("properties", {}).get("type", {}).get("const")
        if const is not None:
            out.append((const, b["then"]))
    return out


def _nested(name: str, s: dict):
    """(its title, the table) when key ``name`` with schema ``s`` holds a table with keys
    (``[name]``) or an array of tables (``[[name]]``); None otherwise."""
    if is_table(s) and s.get("properties"):
        return f"[{name}]", s
    if s.get("type") == "array" and is_table(s.get("items")):
        return f"[[{name}]]", resolve_ref(s["items"])
    return None


def _keys(table: dict, prefix: str = "") -> list[str]:
    table = resolve_ref(table)
    required = set(table.get("required", ()))
    varies = {k for _, then in _branches(table) for k, v in then.get("properties", {}).items()
              if isinstance(v, dict)}
    rows = ["| Key | Expected | Default | Description |", "|---|---|---|---|"]
    for key, s in table.get("properties", {}).items():
        s = resolve_ref(s)
        want = "depends on `type` (below)" if key in varies else expected(s)
        if nested := _nested(f"{prefix}{key}", s):
            want = f"{'tables' if s.get('type') == 'array' else 'a table'}, see {nested[0]}"
        default = "required" if key in required else \
            f"`{show(s['default'])}`" if "default" in s else ""
        rows.append(f"| `{key}` | {_cell(want)} | {default} | {_cell(s.get('description', ''))} |")
    return rows


def _types(table: dict) -> list[str]:
    table = resolve_ref(table)
    rows = ["| `type` | Needs | May have | Condition |", "|---|---|---|---|"]
    common = set(table.get("required", ())) | {"type"}
    for kind, then in _branches(table):
        props = then.get("properties", {})
        needs = [k for k in then.get("required", ())]
        may = [k for k in table["properties"] if k not in common and k not in needs
               and props.get(k, True) is not False]
        detail = [f"`{k}`: {expected(props[k])}" for k in needs + may
                  if isinstance(props.get(k), dict)]
        rows.append(f"| `{kind}` | {', '.join(f'`{k}`' for k in needs) or '-'} | "
                    f"{', '.join(f'`{k}`' for k in may) or '-'} | "
                    f"{_cell(then.get('description', ''))}"
                    f"{' (' + _cell('; '.join(detail)) + ')' if detail else ''} |")
    return rows


def _section(name: str, s: dict, heading: str) -> list[str]:
    """The section of the table (or array of tables) ``name`` and of the tables nested in it;
    [] for a key that holds no table."""
    s = resolve_ref(s)
    if not (nested := _nested(name, s)):
        return []
    title, table = nested
    lines = ["", f"{heading} {title}", "", s.get("description", "")]
    if "oneOf" in table:
        keys = [b["required"][0] for b in table["oneOf"]]
        lines += ["", f"Exactly one of {' or '.join(f'`{k}`' for k in keys)}."]
    for k, deps in table.get("dependentRequired", {}).items():
        lines += ["", f"`{k}` only together with {', '.join(f'`{d}`' for d in deps)}."]
    lines += [""] + _keys(table, f"{name}.")
    if _branches(table):
        lines += ["", "Each `type` takes its own keys; any other key is an error.", ""]
        lines += _types(table)
    for key, sub in table.get("properties", {}).items():
        lines += _section(f"{name}.{key}", sub, heading + "#")
    return lines


def case_file_markdown() -> str:
    """The reference of the case-file format as Markdown text."""
    schema = case_schema()
    lines = [HEADER, "", f"# {schema['title']} reference", "", schema["description"], "",
             ("A case file that breaks a rule below is rejected with one line per fault, naming "
              "the file and the key, e.g."), "",
             "```",
             ("phantom.toml: [material].E: expected a finite number in [1e-09, 1e+12], found "
              "true (a boolean)"),
             ("phantom.toml: [mesh].sise: expected a key of [mesh] (file, builtin, size), found "
              "unknown key 'sise' (did you mean 'size'?)"),
             "```", "",
             ("Arrays of tables are counted from 1 in file order: `[[boundary]][2]` is the second "
              "`[[boundary]]` table. Unknown keys are errors everywhere."), "",
             "## Top level", ""]
    lines += _keys(schema)
    for key, s in schema["properties"].items():
        lines += _section(key, s, "##")
    lines += ["", "## Vectors", "",
              ("A vector has one number per space dimension: 3 on a 3D mesh, 2 on a 2D mesh "
               "(checked once the mesh is read); a gradient is a square matrix of that size. "
              "Regions are checked against the mesh too: an unknown one is an error that lists "
              "the regions there."), ""]
    return "\n".join(lines)
