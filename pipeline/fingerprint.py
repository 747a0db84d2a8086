"""Code fingerprints: the source a stage runs and the package versions it uses, for its content keys.

Without them a code change silently reuses stale shards (a changed constant would leave every rollout "done").
The rule, for the module that defines a stage class:

* **Code**: that module and every module of the project it imports, transitively -- top-level imports and imports
  inside functions alike, since both are code the stage may run. A module is *the project's* when its file lies
  outside the standard library and outside ``site-packages`` (the repository's packages, and test modules on
  ``sys.path``). Each contributes a digest of its **normalised source**: the syntax tree (``ast``) with docstrings
  removed, so comments, blank lines, line breaks, formatting and docstrings do not count; any change to what runs
  (a constant, an expression, an import, a signature) does.
* **Packages**: every third-party distribution those modules import (``mujoco``, ``numpy``, ``trimesh``, ``coacd``,
  ...), by installed version, and the Python version. Upgrading one makes the stages that import it stale.

The walk reads source files with :mod:`ast` and finds them on disk from their top-level package (located with
:func:`importlib.util.find_spec`, which imports nothing for a top-level name). Each file is read once per process;
a stage's fingerprint is computed once per process (``gen status`` and ``gen run`` compute the same thing).

Parsing and normalising every module is paid by every ``gen run`` and ``gen status`` before they plan anything
(docs/decisions/2026-12-03-engine-at-scale.md), so inside :func:`module_cache` (which both open on ``run.cache_dir``) a
module's (digest, imports) is kept in ``<cache_dir>/fingerprints/<module>.json`` under the sha256 of its source bytes,
the module name and the Python version: a cached answer is used only for the very bytes it was computed from, so the
cache changes no key. A damaged cache file is ignored and rewritten; an unwritable folder leaves the cache unused.
"""

from __future__ import annotations

import ast
import contextlib
import functools
import hashlib
import importlib.metadata
import importlib.util
import json
import os
import platform
import sys
import sysconfig
from collections.abc import Iterator
from pathlib import Path

__all__ = ["CODE_PREFIX", "PACKAGE_PREFIX", "module_cache", "stage_fingerprint"]

CODE_PREFIX = "code:"
"""Key-part name prefix of a module's digest: ``code:graspgen/sim/lift.py``."""
PACKAGE_PREFIX = "package:"
"""Key-part name prefix of a package's version: ``package:mujoco``."""

_DIGEST_CHARS = 16
"""Hex characters kept of each module's sha256 (64 bits: enough to notice an edit; the key hashes them all)."""

_CACHE_FORMAT = 1
"""Version of what a cache file holds: bump it when :func:`_digest` or :func:`_imported_names` change."""

_cache_dir: Path | None = None
"""Folder of the module cache in use (:func:`module_cache`); None outside one."""

_EXTERNAL_DIRS = tuple(
    Path(p).resolve()
    for p in {sysconfig.get_paths()[k] for k in ("stdlib", "platstdlib", "purelib", "platlib")}
)


@contextlib.contextmanager
def module_cache(folder: str | os.PathLike) -> Iterator[None]:
    """Within the block, each module's normalised-source digest and imports are read from (or written to)
    ``folder/fingerprints/``, under the sha256 of the module's source bytes: the answers are the same, only
    faster."""
    global _cache_dir
    saved, _cache_dir = _cache_dir, Path(folder) / "fingerprints"
    try:
        yield
    finally:
        _cache_dir = saved


@functools.cache
def stage_fingerprint(module: str) -> dict[str, str]:
    """Key parts for the code and packages behind ``module`` (a stage class's ``__module__``).

    Returns
    -------
    dict
        ``{"code:<path>": digest}`` for ``module`` and each project module it imports (paths relative to the
        folder their top-level package sits in, e.g. ``graspgen/sim/lift.py``), and ``{"package:<name>": version}``
        for each third-party distribution they import, plus ``package:python``. Sorted by name.
    """
    code: dict[str, str] = {}
    packages: dict[str, str] = {"python": platform.python_version()}
    seen: set[str] = set()
    todo = [module]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        info = _module_info(name)
        if info is None:
            continue
        path, digest, imports = info
        code[CODE_PREFIX + path] = digest
        for imported in imports:
            top = imported.split(".")[0]
            if top in sys.stdlib_module_names or top == "__future__":
                continue
            found = _project_modules(imported)
            if found is None:
                packages.update(_distribution_versions(top))
            else:
                todo.extend(found)
    parts = {**code, **{PACKAGE_PREFIX + k: v for k, v in packages.items()}}
    return dict(sorted(parts.items()))


@functools.cache
def _module_info(name: str) -> tuple[str, str, tuple[str, ...]] | None:
    """(path as shown, digest, imported names) of the project module ``name``; None when it is not the project's.
    Each file is read and parsed once per process, however many stages import it."""
    origin = _project_file(name)
    if origin is None:
        return None
    source = origin.read_bytes()
    cache_file = None if _cache_dir is None else _cache_dir / f"{name}.json"
    stamp = {"format": _CACHE_FORMAT, "python": platform.python_version(), "module": name,
             "source_sha256": hashlib.sha256(source).hexdigest()}
    cached = None if cache_file is None else _read_cache(cache_file, stamp)
    if cached is not None:
        digest, imports = cached
    else:
        tree = ast.parse(source.decode("utf-8"), filename=str(origin))
        imports = tuple(_imported_names(tree, name, origin.name == "__init__.py"))
        digest = _digest(tree)
        if cache_file is not None:
            _write_cache(cache_file, {**stamp, "digest": digest, "imports": list(imports)})
    return _relative_path(name, origin), digest, imports


def _read_cache(path: Path, stamp: dict[str, object]) -> tuple[str, tuple[str, ...]] | None:
    """(digest, imports) from a cache file written for exactly ``stamp`` (same source bytes, module, Python and
    cache format); None when there is none, it is for other bytes, or it cannot be read."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        if all(data.get(k) == v for k, v in stamp.items()):
            digest, imports = data["digest"], data["imports"]
            if isinstance(digest, str) and isinstance(imports, list) and all(isinstance(i, str) for i in imports):
                return digest, tuple(imports)
    except (OSError, ValueError, AttributeError, KeyError):
        pass
    return None


def _write_cache(path: Path, data: dict[str, object]) -> None:
    """Write a cache file atomically (temp file in the same folder, then ``os.replace``); skipped quietly when the
    folder is not writable, since the cache only saves time."""
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(json.dumps(data, sort_keys=True), encoding="utf-8")
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)


@functools.cache
def _project_root(top: str) -> Path | None:
    """The folder of the project's top-level package or module ``top``; None for the standard library and
    third-party packages. Looks the name up without importing it."""
    try:
        spec = importlib.util.find_spec(top)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.origin or not spec.origin.endswith(".py"):
        return None  # built-in, extension module, namespace package
    origin = Path(spec.origin).resolve()
    if _is_external(origin):
        return None
    return origin.parent.parent if origin.name == "__init__.py" else origin.parent


@functools.cache
def _project_file(name: str) -> Path | None:
    """The source file of the project module ``name`` (``a/b.py`` or ``a/b/__init__.py``), or None. Looked up
    once per process: the walk asks for the same names thousands of times (every stage imports the library), and
    each look-up is a few file stats (a third of ``gen status``'s planning at 100 objects)."""
    top, *rest = name.split(".")
    root = _project_root(top)
    if root is None:
        return None
    if not rest:
        package = root / top / "__init__.py"
        return package if package.is_file() else (root / f"{top}.py" if (root / f"{top}.py").is_file() else None)
    base = root.joinpath(top, *rest)
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _is_external(path: Path) -> bool:
    return any(path.is_relative_to(d) for d in _EXTERNAL_DIRS) or "site-packages" in path.parts


def _relative_path(module: str, origin: Path) -> str:
    """``graspgen/sim/lift.py`` for ``graspgen.sim.lift``: the path below the folder its top package sits in."""
    depth = module.count(".") + (1 if origin.name == "__init__.py" else 0)
    return origin.relative_to(origin.parents[depth]).as_posix()


def _digest(tree: ast.Module) -> str:
    """sha256 of the syntax tree without docstrings (changes ``tree``: call it after reading the imports)."""
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (
            isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
            and body
            and isinstance(body[0], ast.Expr)
            and isinstance(body[0].value, ast.Constant)
            and isinstance(body[0].value.value, str)
        ):
            node.body = body[1:] or [ast.Pass()]
    normalised = ast.dump(tree, annotate_fields=False, include_attributes=False)
    return hashlib.sha256(normalised.encode()).hexdigest()[:_DIGEST_CHARS]


def _imported_names(tree: ast.Module, module: str, is_package: bool) -> Iterator[str]:
    """Absolute names of what ``module`` imports: ``a.b`` for ``import a.b``; ``a.b`` and ``a.b.c`` for
    ``from a.b import c`` (``c`` may be a submodule or an attribute; :func:`_project_module` sorts that out)."""
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1])
                base = f"{base}.{node.module}" if node.module else base
            else:
                base = node.module or ""
            yield base
            yield from (f"{base}.{alias.name}" for alias in node.names if alias.name != "*")


@functools.cache
def _project_modules(name: str) -> tuple[str, ...] | None:
    """The project modules behind an imported name (the module and its parent packages), or None when the name
    is third-party. ``a.b.c`` where ``c`` is an attribute of module ``a.b`` resolves to ``a``, ``a.b``."""
    parts = name.split(".")
    if _project_root(parts[0]) is None:
        return None
    for end in range(len(parts), 0, -1):
        if _project_file(".".join(parts[:end])) is not None:
            return tuple(".".join(parts[:i]) for i in range(1, end + 1))
    return None


@functools.cache
def _packages_distributions() -> dict[str, list[str]]:
    return importlib.metadata.packages_distributions()


@functools.cache
def _distribution_versions(top_level: str) -> dict[str, str]:
    """``{distribution: version}`` of the installed distributions that provide the import name ``top_level``."""
    try:
        return {top_level.lower(): importlib.metadata.version(top_level)}  # the usual case, and fast
    except (importlib.metadata.PackageNotFoundError, ValueError):
        names = _packages_distributions().get(top_level, [])  # e.g. yaml -> pyyaml, PIL -> pillow: scans once
    versions = {}
    for dist in names:
        try:
            versions[dist.lower()] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            continue
    return versions
