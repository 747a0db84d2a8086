"""The column reference of the tables a user reads (``docs/columns.md``), generated from the code's own column docs.

Every published table and ``gen evaluate``'s output is described where it is built: the merged ``grasps.parquet``
by :data:`graspgen.io.dataset_table.COLUMN_DOCS` (also stored in each Parquet field's metadata), the other tables
by the ``column / type / meaning`` table in the docstring of the module that defines their ``SCHEMA``.
:func:`column_reference` turns those into one Markdown page, with the types read from the schemas themselves, and
fails (:class:`~graspgen.errors.NotFoundError`) where a schema column has no description or a description names no
column, so the page cannot drift from the code. Regenerate it after adding a column::

    python -m graspgen.workflows.column_docs --write      # writes docs/columns.md
    python -m graspgen.workflows.column_docs              # prints it

The merged table's layout is the one :func:`graspgen.io.dataset_table.join_scene` gives the per-stage schemas (the
same call the ``dataset`` stage makes), so its column order, renames and types are the published file's.
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

import pyarrow as pa

from graspgen.errors import NotFoundError
from graspgen.io.dataset_table import COLUMN_DOCS, TABLES, join_scene
from graspgen.workflows import (
    evaluate_columns,
    metrics,
    object_grasps,
    placed_grasps,
    robustness,
    rollouts,
    scene_grasps,
)

__all__ = ["DOCS_PATH", "column_reference", "docstring_columns", "type_name"]

DOCS_PATH = Path(__file__).resolve().parents[2] / "docs" / "columns.md"
"""Where ``--write`` puts the page: ``docs/columns.md`` of the repository."""

_STAGE_SCHEMAS: dict[str, pa.Schema] = {
    "grasps": scene_grasps.SCHEMA,
    "rollouts": rollouts.SCHEMA,
    "robustness": robustness.SCHEMA,
    "metrics": metrics.SCHEMA,
}
"""The schema of each table stage joined into ``grasps.parquet`` (:data:`graspgen.io.dataset_table.TABLES`)."""

_HEADER = """# Column reference

Generated from the code's column descriptions by `python -m graspgen.workflows.column_docs --write`; do not edit it
by hand (`tests/test_docs.py` fails when it is not current). Types are Arrow's: `float64[16]` is a fixed-size list
(a 4x4 matrix, row-major), `list<float64>` a variable-length one. Units: metres, kilograms, seconds, radians.
See [format.md](format.md) for the files themselves.
"""

_RST_ROLE = re.compile(r":[a-z]+:`~?([^`]+)`")


def type_name(arrow_type: pa.DataType) -> str:
    """A short name of an Arrow type: ``float64``, ``float64[16]`` (fixed-size list), ``list<int8>``."""
    if pa.types.is_fixed_size_list(arrow_type):
        return f"{type_name(arrow_type.value_type)}[{arrow_type.list_size}]"
    if pa.types.is_list(arrow_type):
        return f"list<{type_name(arrow_type.value_type)}>"
    return {"double": "float64", "float": "float32"}.get(str(arrow_type), str(arrow_type))


def _markdown(text: str) -> str:
    """reStructuredText inline markup as Markdown: ``x`` and :role:`x` become `x`; pipes escaped for tables, and
    ``<`` / ``>`` outside code escaped so that ``scenes/<scene_id>.h5`` is not read as an HTML tag."""
    parts = _RST_ROLE.sub(r"`\1`", text).replace("``", "`").split("`")
    for i in range(0, len(parts), 2):  # outside code spans
        parts[i] = parts[i].replace("<", "&lt;").replace(">", "&gt;")
    return "`".join(parts).replace("|", "\\|")


def docstring_columns(module: ModuleType) -> dict[str, str]:
    """The ``column  type  meaning`` table of a module's docstring, as ``{column: meaning}``.

    The table is a simple reStructuredText table whose header row starts with ``column``; a row's first word is the
    column name, its second the type, the rest the meaning; an indented line continues the row above.

    Raises
    ------
    NotFoundError
        The docstring has no such table.
    """
    lines = (module.__doc__ or "").splitlines()
    header = next((i for i, line in enumerate(lines) if re.match(r"column\s+type\s+meaning\s*$", line)), None)
    if header is None or header + 1 >= len(lines) or not lines[header + 1].startswith("="):
        raise NotFoundError(f"{module.__name__}: its docstring has no 'column  type  meaning' table")
    columns: dict[str, str] = {}
    last = ""
    for line in lines[header + 2:]:
        if line.startswith("="):
            break
        if line[:1].isspace():
            columns[last] = f"{columns[last]} {line.strip()}"
            continue
        name, _, meaning = (line.split(None, 2) + ["", ""])[:3]
        columns[name] = meaning.strip()
        last = name
    return columns


def _described(module: ModuleType, schema: pa.Schema) -> list[tuple[pa.Field, str]]:
    """Each field of ``schema`` with its meaning from ``module``'s docstring table, which must list exactly them."""
    docs = docstring_columns(module)
    missing = [f.name for f in schema if f.name not in docs]
    extra = [name for name in docs if name not in schema.names]
    if missing or extra:
        raise NotFoundError(f"{module.__name__}: the docstring table does not match SCHEMA: undocumented columns "
                            f"{missing}, documented columns not in SCHEMA {extra}")
    return [(field, docs[field.name]) for field in schema]


def merged_fields() -> list[tuple[pa.Field, str, str]]:
    """The columns of ``grasps.parquet``: (field, stage, description), in the published order."""
    table = join_scene([(stage, _STAGE_SCHEMAS[stage].empty_table()) for stage in TABLES], "")
    return [(f, f.metadata[b"stage"].decode(), f.metadata[b"description"].decode()) for f in table.schema]


def _table(rows: Sequence[tuple[str, ...]], header: tuple[str, ...]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def _section(title: str, intro: str, fields: Sequence[tuple[pa.Field, str]]) -> list[str]:
    rows = [(f"`{f.name}`", f"`{type_name(f.type)}`", _markdown(doc)) for f, doc in fields]
    return ["", f"## {title}", "", intro, "", *_table(rows, ("column", "type", "meaning"))]


def column_reference() -> str:
    """The whole page (``docs/columns.md``): every column of every published table and of ``gen evaluate``'s output.

    Raises
    ------
    NotFoundError
        A column of ``grasps.parquet`` has no entry in ``COLUMN_DOCS``, or another table's docstring table and its
        ``SCHEMA`` do not list the same columns.
    """
    merged = merged_fields()
    undocumented = [f.name for f, _, _ in merged if f.name not in COLUMN_DOCS]
    if undocumented:
        raise NotFoundError(f"graspgen.io.dataset_table.COLUMN_DOCS: no description of {undocumented}")
    lines = [_HEADER.rstrip("\n")]
    rows = [(f"`{f.name}`", f"`{type_name(f.type)}`", stage, _markdown(doc)) for f, stage, doc in merged]
    lines += ["", "## grasps.parquet", "",
              "One row per scene grasp, the per-scene tables of the stages "
              f"{', '.join(f'`{s}`' for s in TABLES)} joined on `(scene_id, grasp_id)`, sorted by `scene_id`, "
              "`grasp_id`. The same descriptions are in each Parquet field's metadata (`description`, `stage`) and "
              "in the dataset card.", "", *_table(rows, ("column", "type", "stage", "meaning"))]
    lines += _section("object_grasps.parquet", "Each object's object-centric set (the `object_grasps` stage: "
                      "free-space labels, grasps from every side), one row per kept grasp, by object in trial order.",
                      _described(object_grasps, object_grasps.SCHEMA))
    lines += _section("placed_grasps.parquet", "The object-centric sets placed in the scenes (the `placed_grasps` "
                      "stage: no new rollouts), one row per placed grasp, by scene.",
                      _described(placed_grasps, placed_grasps.SCHEMA))
    lines += _section("gen evaluate output", "`gen evaluate -o labels.parquet` (`evaluate_grasps`): one row per "
                      "input grasp, in input order.", _described(evaluate_columns, evaluate_columns.SCHEMA))
    extra = [(f, COLUMN_DOCS[f.name]) for f in evaluate_columns.ROBUSTNESS_FIELDS]
    lines += ["", "With `--robustness N` (`robustness=RobustnessParams(...)`) these columns follow, described as in "
              "`grasps.parquet`:", "",
              *_table([(f"`{f.name}`", f"`{type_name(f.type)}`", _markdown(d)) for f, d in extra],
                      ("column", "type", "meaning"))]
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> None:
    """``python -m graspgen.workflows.column_docs [--write]``: print the page, or write it to :data:`DOCS_PATH`."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help=f"write {DOCS_PATH} instead of printing")
    args = parser.parse_args(argv)
    text = column_reference()
    if args.write:
        DOCS_PATH.parent.mkdir(parents=True, exist_ok=True)
        DOCS_PATH.write_text(text, encoding="utf-8")
    else:
        print(text, end="")


if __name__ == "__main__":
    main()
