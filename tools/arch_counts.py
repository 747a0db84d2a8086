"""Print the architecture counts of issue 42 for a checkout: settings, branches, MuJoCo imports, docstrings, helpers.

Usage: ``python tools/arch_counts.py [--root PATH]`` (default: this checkout). ``--root`` may name another checkout
(a ``git worktree`` of an older commit): its code is read, and its ``stages.config.Config`` imported, from there.

The counts, each over the engine, the library, the stages and the command line (``pipeline``, ``graspgen``,
``stages``, ``graspgen_cli`` and ``shared_utils`` where present; tests, studies and bench are left out):

- ``config_leaf_keys``: settings reachable from ``stages.config.Config``, walking the field types: a field whose
  type is a settings dataclass (``X`` or ``X | None``) is a section and is walked, any other field is one leaf key;
  keys a section derives (``config_derived``) are not settings and are not counted.
- ``default_yaml_keys``: leaf keys that ``configs/default.yaml`` sets (a list is one key).
- ``protocol_branches`` / ``backend_branches`` outside ``graspgen/sim`` (and, for reference, protocol branches in
  it): comparisons (``==``, ``!=``, ``in``,
  ``not in``) with a name or attribute called ``protocol`` / ``backend`` on either side.
- ``mujoco_modules_outside_sim``: modules outside ``graspgen/sim`` with an import (at any depth, function-level
  included) of ``mujoco``, ``mujoco_warp`` or ``warp``.
- ``docstring_share``: lines of bare string statements (module, class, function and attribute docstrings) over all
  lines of the files.
- ``duplicated_helpers``: public top-level function names (``main`` aside: every command has one) defined in more
  than one package (a package: the folder of the module, e.g. ``graspgen.io`` and ``pipeline``).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import sys
import types
import typing
from collections import defaultdict
from pathlib import Path

PACKAGES = ("pipeline", "graspgen", "stages", "graspgen_cli", "shared_utils")
MUJOCO = {"mujoco", "mujoco_warp", "warp"}


def _sources(root: Path) -> list[Path]:
    """The Python files of :data:`PACKAGES` under ``root``, sorted."""
    return sorted(f for p in PACKAGES if (root / p).is_dir() for f in (root / p).rglob("*.py")
                  if "__pycache__" not in f.parts)


def _named(node: ast.AST, word: str) -> bool:
    return (isinstance(node, ast.Name) and node.id == word) or (isinstance(node, ast.Attribute) and node.attr == word)


def _branches(tree: ast.AST, word: str) -> int:
    """Comparisons with ``==``, ``!=``, ``in`` or ``not in`` that have a name or attribute ``word`` on either side."""
    ops = (ast.Eq, ast.NotEq, ast.In, ast.NotIn)
    return sum(1 for n in ast.walk(tree) if isinstance(n, ast.Compare) and any(isinstance(o, ops) for o in n.ops)
               and any(_named(side, word) for side in [n.left, *n.comparators]))


def _imports_mujoco(tree: ast.AST) -> bool:
    for n in ast.walk(tree):
        if isinstance(n, ast.Import) and any(a.name.split(".")[0] in MUJOCO for a in n.names):
            return True
        if isinstance(n, ast.ImportFrom) and n.level == 0 and (n.module or "").split(".")[0] in MUJOCO:
            return True
    return False


def _docstring_lines(tree: ast.AST) -> int:
    """Lines of bare string expression statements (docstrings and attribute docstrings)."""
    return sum(n.end_lineno - n.lineno + 1 for n in ast.walk(tree)
               if isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant) and isinstance(n.value.value, str))


def code_counts(root: Path) -> dict[str, object]:
    """The counts read from the source files under ``root`` (module docstring)."""
    protocol = protocol_sim = backend = doc_lines = all_lines = 0
    mujoco_modules: list[str] = []
    defined: dict[str, set[str]] = defaultdict(set)
    for path in _sources(root):
        rel = path.relative_to(root)
        text = path.read_text(encoding="utf-8")
        tree = ast.parse(text)
        outside_sim = rel.parts[:2] != ("graspgen", "sim")
        if not outside_sim:
            protocol_sim += _branches(tree, "protocol")
        else:
            protocol += _branches(tree, "protocol")
            backend += _branches(tree, "backend")
            if _imports_mujoco(tree):
                mujoco_modules.append(rel.as_posix())
        doc_lines += _docstring_lines(tree)
        all_lines += len(text.splitlines())
        package = ".".join(rel.parts[:-1])
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not node.name.startswith("_") \
                    and node.name != "main":
                defined[node.name].add(package)
    duplicated = {name: sorted(pkgs) for name, pkgs in sorted(defined.items()) if len(pkgs) > 1}
    return {
        "protocol_branches_outside_sim": protocol,
        "protocol_branches_in_sim": protocol_sim,
        "backend_branches_outside_sim": backend,
        "mujoco_modules_outside_sim": mujoco_modules,
        "docstring_lines": doc_lines,
        "lines": all_lines,
        "docstring_share": round(doc_lines / all_lines, 3) if all_lines else 0.0,
        "duplicated_helpers": duplicated,
    }


def _section(tp: object) -> type | None:
    """The settings dataclass a field type names (``X`` or ``X | None``), else None."""
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return tp
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        found = [a for a in typing.get_args(tp) if dataclasses.is_dataclass(a) and isinstance(a, type)]
        return found[0] if len(found) == 1 else None
    return None


def leaf_keys(cls: type, skip: frozenset[str] = frozenset()) -> int:
    """Leaf settings reachable from the dataclass ``cls`` (module docstring); the keys a section derives (its
    ``config_derived``, :data:`pipeline.config.DERIVED`, where the checkout has it) and ``skip`` are no settings."""
    hints = typing.get_type_hints(cls)
    skip = skip | set(getattr(cls, "config_derived", {}))
    total = 0
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        section = _section(hints[f.name])
        inner = frozenset(p.removeprefix(f"{f.name}.") for p in skip if p.startswith(f"{f.name}."))
        total += leaf_keys(section, inner) if section is not None else 1
    return total


def _yaml_leaves(node: object) -> int:
    if isinstance(node, dict):
        return sum(_yaml_leaves(v) for v in node.values())
    return 1


def config_counts(root: Path) -> dict[str, int]:
    """The settings counts: leaf keys of ``Config`` (imported from ``root``) and keys ``configs/default.yaml`` sets."""
    import yaml

    sys.path.insert(0, str(root))
    from stages.config import Config

    with open(root / "configs" / "default.yaml", encoding="utf-8") as f:
        default = yaml.safe_load(f) or {}
    return {"config_leaf_keys": leaf_keys(Config), "default_yaml_keys": _yaml_leaves(default)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1], help="the checkout")
    args = parser.parse_args(argv)
    root = args.root.resolve()
    counts = {**config_counts(root), **code_counts(root)}
    for key, value in counts.items():
        if isinstance(value, list):
            print(f"{key}: {len(value)}" + "".join(f"\n    {v}" for v in value))
        elif isinstance(value, dict):
            print(f"{key}: {len(value)}" + "".join(f"\n    {k}: {', '.join(v)}" for k, v in value.items()))
        else:
            print(f"{key}: {value}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
