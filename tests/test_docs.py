"""The documentation stays true to the tree: the generated column reference is current, the README is short, links,
anchors, file paths and module names in README.md, ARCHITECTURE.md, docs/*.md, docs/decisions/*.md and
studies/README.md point to things that exist, and the README's config example is a valid config."""

from __future__ import annotations

import ast
import re
import types
from pathlib import Path

import pyarrow as pa
import pytest

from graspgen.errors import NotFoundError
from graspgen.io.dataset_table import LABEL_TYPES, REQUIRED_SCHEMA
from graspgen.workflows import column_docs

ROOT = Path(__file__).resolve().parents[1]
DECISIONS = sorted((ROOT / "docs" / "decisions").glob("*.md"))
DOCS = [ROOT / "README.md", ROOT / "ARCHITECTURE.md", *sorted((ROOT / "docs").glob("*.md")),
        ROOT / "studies" / "README.md", *DECISIONS]
WRITTEN = [p for p in DOCS if p.name != "columns.md"]  # columns.md quotes the code's docstrings as they are
CURRENT = [p for p in WRITTEN if p not in DECISIONS]  # a decision page is dated history on purpose
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
CODE_PATH = re.compile(r"`((?:graspgen|graspgen_cli|pipeline|stages|bench|tests|assets|configs|tools)/[^`\s]*)`")
MODULE_NAME = re.compile(r"`(graspgen(?:\.\w+)+)`")


def _anchors(path: Path) -> set[str]:
    """GitHub's anchors of a Markdown file's headings: lower case, punctuation dropped, spaces as hyphens."""
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    heads = re.findall(r"^#+ (.+)$", text, re.M)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in heads}


def _top_level_names(module: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.parse(module.read_text()).body:
        if isinstance(node, (ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names.update(n.id for target in targets for n in ast.walk(target) if isinstance(n, ast.Name))
            if "__all__" in names and isinstance(node.value, (ast.List, ast.Tuple)):  # lazily exported names too
                names.update(e.value for e in node.value.elts if isinstance(e, ast.Constant))
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
    return names


def _module_name_problem(dotted: str) -> str | None:
    """Why ``graspgen.a.b[.Name[.attr]]`` names nothing in the tree, or None: the longest prefix that is a module
    file or package, then a top-level name of it."""
    parts = dotted.split(".")
    for n in range(len(parts), 0, -1):
        base = ROOT.joinpath(*parts[:n])
        module = base.with_suffix(".py") if base.with_suffix(".py").is_file() else base / "__init__.py"
        if module.is_file():
            rest = parts[n:]
            if rest and rest[0] not in _top_level_names(module):
                return f"{'.'.join(parts[:n])} defines no {rest[0]!r}"
            return None
    return "no such module"


def test_the_column_reference_is_the_generated_one():
    """docs/columns.md is exactly what the code generates: regenerate it when a column or its description changes."""
    expected = column_docs.column_reference()
    actual = (ROOT / "docs" / "columns.md").read_text(encoding="utf-8")
    assert actual == expected, "docs/columns.md is stale: run python -m graspgen.workflows.column_docs --write"


def test_the_column_reference_lists_every_required_and_label_column_of_grasps_parquet():
    merged = {f.name: f.type for f, _, _ in column_docs.merged_fields()}
    for field in REQUIRED_SCHEMA:
        assert merged[field.name] == field.type, field.name
    for name, arrow_type in LABEL_TYPES.items():
        assert merged[name] == arrow_type, name
    text = (ROOT / "docs" / "columns.md").read_text()
    section = text.split("## grasps.parquet", 1)[1].split("\n## ", 1)[0]
    assert re.findall(r"^\| `(\w+)` \|", section, re.M) == list(merged)


def test_a_column_without_a_description_stops_the_generator(monkeypatch):
    schemas = dict(column_docs._STAGE_SCHEMAS)
    schemas["metrics"] = schemas["metrics"].append(pa.field("new_metric", pa.float64()))
    monkeypatch.setattr(column_docs, "_STAGE_SCHEMAS", schemas)
    with pytest.raises(NotFoundError, match="no description of \\['new_metric'\\]"):
        column_docs.column_reference()


def test_a_described_new_column_makes_the_checked_in_page_stale(monkeypatch):
    schemas = dict(column_docs._STAGE_SCHEMAS)
    schemas["metrics"] = schemas["metrics"].append(pa.field("new_metric", pa.float64()))
    monkeypatch.setattr(column_docs, "_STAGE_SCHEMAS", schemas)
    monkeypatch.setitem(column_docs.COLUMN_DOCS, "new_metric", "a new label, unit-free")
    text = column_docs.column_reference()
    assert "| `new_metric` | `float64` | metrics | a new label, unit-free |" in text
    assert text != (ROOT / "docs" / "columns.md").read_text()


def test_docstring_tables_are_read_row_by_row_with_continuation_lines():
    module = types.ModuleType("fake_table", """Output:

    ==========  =============  ==========================
    column      type           meaning
    ==========  =============  ==========================
    a           int32          first, ``code`` of
                               :class:`x.Y`
    b_longer_name float64      second | with a pipe
    ==========  =============  ==========================
    """.replace("\n    ", "\n"))
    assert column_docs.docstring_columns(module) == {"a": "first, ``code`` of :class:`x.Y`",
                                                     "b_longer_name": "second | with a pipe"}
    schema = pa.schema([("a", pa.int32()), ("b_longer_name", pa.float64())])
    rows = [(f.name, doc) for f, doc in column_docs._described(module, schema)]
    assert rows == [("a", "first, ``code`` of :class:`x.Y`"), ("b_longer_name", "second | with a pipe")]
    assert column_docs._markdown(rows[0][1]) == "first, `code` of `x.Y`"
    assert column_docs._markdown("a | b <id>") == "a \\| b &lt;id&gt;"
    with pytest.raises(NotFoundError, match=r"undocumented columns \['c'\], documented columns not in SCHEMA"):
        column_docs._described(module, schema.append(pa.field("c", pa.int8())))
    with pytest.raises(NotFoundError, match="no 'column  type  meaning' table"):
        column_docs.docstring_columns(types.ModuleType("empty", "No table here."))


def test_type_names():
    assert column_docs.type_name(pa.list_(pa.float64(), 16)) == "float64[16]"
    assert column_docs.type_name(pa.list_(pa.int8())) == "list<int8>"
    assert column_docs.type_name(pa.float64()) == "float64"
    assert column_docs.type_name(pa.bool_()) == "bool"


def test_the_readme_is_at_most_250_lines():
    assert len((ROOT / "README.md").read_text().splitlines()) <= 250


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_relative_links_and_anchors_point_to_what_exists(doc):
    problems = []
    for target in LINK.findall(doc.read_text()):
        if re.match(r"[a-z]+:", target):
            continue  # http:, https:, mailto:
        file, _, anchor = target.partition("#")
        path = (doc.parent / file).resolve() if file else doc
        if not path.exists():
            problems.append(f"{target}: no such file")
        elif anchor and path.suffix == ".md" and anchor not in _anchors(path):
            problems.append(f"{target}: no heading #{anchor} in {path.name}")
    assert not problems, f"{doc.name}: {problems}"


@pytest.mark.parametrize("doc", WRITTEN, ids=lambda p: p.name)
def test_paths_and_module_names_in_the_docs_exist(doc):
    text = doc.read_text()
    problems = []
    for token in CODE_PATH.findall(text):
        file, _, test = token.partition("::")
        if re.search(r"[<>*{]", file) or not re.search(r"(\.\w+|/)$", file):
            continue  # a pattern (`stages/<name>.py`) or a name inside a file (`graspgen/firm_hold`), not a file
        path = ROOT / file.rstrip("/")
        if not path.exists():
            problems.append(f"{token}: no such file")
        elif test and f"def {test}(" not in path.read_text():
            problems.append(f"{token}: no such test")
    problems += [f"{name}: {why}" for name in MODULE_NAME.findall(text) if (why := _module_name_problem(name))]
    assert not problems, f"{doc.name}: {problems}"


@pytest.mark.parametrize("doc", CURRENT, ids=lambda p: p.name)
def test_the_docs_tell_no_history(doc):
    found = re.findall(r"\bissues? \d+|\bthis session\b|\bthe session\b", doc.read_text(), re.I)
    assert not found, f"{doc.name}: {found}"


def test_the_readme_config_example_is_a_valid_config(tmp_path):
    from pipeline.config import load_config
    from stages.project import PROJECT

    (block,) = re.findall(r"```yaml\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    path = tmp_path / "my.yaml"
    path.write_text(block)
    config = load_config(PROJECT.schema, path, [f"run.out={tmp_path / 'out'}"])
    assert list(config.objects.paths) == ["meshes/*.obj"] and config.objects.bundled is False
    assert config.grasps.gripper == "robotiq_2f85_mesh"


def test_the_readme_command_lines_name_real_commands_and_options():
    """Every ``gen ...`` line of the README's command-line block names a command of ``gen`` and only its options
    (also the ``[--option ...]`` of the comment lines under it)."""
    import typer

    from graspgen_cli.app import app

    root = typer.main.get_command(app)
    block = re.search(r"## Command line\n\n```bash\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    problems, command, seen = [], None, []
    for line in block.splitlines():
        code, _, comment = line.partition("#")
        if line.startswith("gen "):
            words, command = code.split()[1:], root
            while words and words[0] in getattr(command, "commands", {}):
                command = command.commands[words.pop(0)]
            if hasattr(command, "commands") or command is root:
                problems.append(f"{line.strip()}: names no command")
                continue
            seen.append(command.name)
            used = re.findall(r"(?<![\w-])(--?[a-z][\w-]*)", code)
        else:
            used = re.findall(r"\[(--[a-z][\w-]*)", comment)
        known = {opt for param in command.params for opt in param.opts + param.secondary_opts} if command else set()
        problems += [f"{line.strip()}: {command.name} has no option {opt}" for opt in used if opt not in known]
    assert not problems, problems
    assert {"run", "status", "evaluate", "validate"} <= set(seen)
