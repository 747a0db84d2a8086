"""Fail when a module or a function outgrows the sizes ARCHITECTURE.md sets.

A module (a ``.py`` file) may have at most :data:`MAX_MODULE_LINES` lines, a function or method at most
:data:`MAX_FUNCTION_LINES` (from its ``def`` line to its last line, decorators and docstring included). Run by
``make lint`` on the library, the engine, the stages and the command line::

    python tools/check_sizes.py graspgen pipeline stages graspgen_cli
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 80


def _python_files(paths: list[str]) -> list[Path]:
    files: list[Path] = []
    for arg in paths:
        path = Path(arg)
        files.extend(sorted(path.rglob("*.py")) if path.is_dir() else [path])
    return files


def oversized(path: Path) -> list[str]:
    """The size faults of one file, one line each: ``path: N lines`` or ``path:LINE name: N lines``."""
    text = path.read_text(encoding="utf-8")
    faults = []
    lines = len(text.splitlines())
    if lines > MAX_MODULE_LINES:
        faults.append(f"{path}: {lines} lines (a module may have {MAX_MODULE_LINES})")
    for node in ast.walk(ast.parse(text, filename=str(path))):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            start = min([node.lineno] + [d.lineno for d in node.decorator_list])
            length = node.end_lineno - start + 1
            if length > MAX_FUNCTION_LINES:
                faults.append(f"{path}:{node.lineno} {node.name}: {length} lines (a function may have "
                              f"{MAX_FUNCTION_LINES})")
    return faults


def main(argv: list[str]) -> int:
    faults = [fault for path in _python_files(argv or ["graspgen", "pipeline", "stages", "graspgen_cli"])
              for fault in oversized(path)]
    for fault in faults:
        print(fault)
    return 1 if faults else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
