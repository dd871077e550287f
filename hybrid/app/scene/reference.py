"""The scene file reference in Markdown, generated from the schema (``docs/scene_reference.md``)."""
from .describe import TYPE_NAMES, allowed_text, default_text
from .schema import SCHEMA, SHAPE, TOP


def reference_markdown():
    """The scene file reference (every table and field, unit, default, allowed values) as Markdown."""
    out = ["# Scene file reference", "",
           "Generated from the schema in `hybrid/app/scene/schema.py` by `python -m hybrid.app.scene > "
           "docs/scene_reference.md`; do not edit by hand.", "",
           "Scene files are TOML, in SI units. Unknown keys are errors. Integers are accepted where "
           "numbers are expected; booleans are not numbers. Vectors are lists of 3 numbers. Mesh paths "
           "are relative to the scene file's folder. Check a file with `hybrid validate <file>`.", ""]
    for section in SCHEMA.values():
        if section is TOP:
            continue
        out += [f"## `{section.heading}`", "", section.doc, ""]
        if section.rules:
            out += [f"- {rule}" for rule in section.rules] + [""]
        out += ["| Field | Type | Unit | Default | Allowed | Description |",
                "|---|---|---|---|---|---|"]
        for f in section.fields:
            doc = f.doc + (" FEM only." if f.fem else "")
            if f.shapes and len(f.shapes) < len(SHAPE.field("type").choices):
                doc += " For " + ", ".join(f"`{s}`" for s in f.shapes) + "."
            cells = [f"`{f.name}`", TYPE_NAMES[f.kind], f.unit or "-", default_text(f),
                     allowed_text(f) or "-", doc]
            out.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
        out.append("")
    return "\n".join(out)
