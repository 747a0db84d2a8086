"""Typed, frozen configuration loaded from YAML.

A config is a tree of frozen dataclasses. :func:`load_config` turns a YAML mapping (plus ``--set key=value``
overrides) into that tree and checks it before any work starts: an unknown key, a wrong type or a value out of
range is a :class:`~pipeline.errors.ConfigError` whose message starts with the key path::

    objects.pahts: unknown key; valid keys: bundled, coacd, density, ...
    objects.density: must be > 0, got -1
    object_grasps.protocol: protocol 'graspgen' was renamed 'graspdatagen'
    rollouts.lift.timestep: moved to physics.timestep

A key or value that was renamed (field metadata :data:`shared_utils.renames.RENAMED_FROM` /
:data:`~shared_utils.renames.RENAMED_VALUES`) or moved (a section's :data:`MOVED`) is answered with its new name;
a key the schema derives (a section's :data:`DERIVED`) is answered with where it comes from.

Range checks live in each dataclass's ``__post_init__`` and raise ``ValueError("field: message")``; the loader
prefixes the section path.
"""

from __future__ import annotations

import dataclasses
import io
import types
import typing
from pathlib import Path
from typing import Any, Literal

import yaml

from pipeline.errors import ConfigError
from shared_utils.renames import RENAMED_FROM, RENAMED_VALUES, renamed_message

__all__ = [
    "DERIVED",
    "FLATTEN",
    "MOVED",
    "RunConfig",
    "field_docs",
    "load_config",
    "parse_override",
    "to_dict",
    "to_yaml",
]


FLATTEN = "config_flatten"
"""Field metadata flag of a field that holds a settings dataclass written at its section's own level: its keys
sit beside the section's other keys in the file, in ``to_dict``, in ``to_yaml`` and in the content keys
(``dataclasses.field(default_factory=Inner, metadata={FLATTEN: True})``), so a section can embed another settings
class without repeating its fields and without changing the keys users write. Its own field docstrings are the
comments ``to_yaml`` writes for them."""


DERIVED = "config_derived"
"""Class attribute of a config section: ``{key path in the section ("prefilter.width_margin"): what it is derived
from}``. Those fields are no settings: a file that sets one fails with an error naming the source, ``to_yaml``
leaves them out, and the schema's ``__post_init__`` fills them in."""

MOVED = "config_moved"
"""Class attribute of a config section: a function of a key path in the section (``"lift.timestep"``) that returns
the key's path now (``"physics.timestep"``) or None. A file that still writes a moved key fails with an error naming
the new one."""


def _leaf_paths(raw: Any, path: tuple[str, ...] = ()) -> typing.Iterator[tuple[str, ...]]:
    """The key paths of the leaves of a nested mapping (an empty mapping is a leaf)."""
    if isinstance(raw, dict) and raw:
        for key, value in raw.items():
            yield from _leaf_paths(value, (*path, str(key)))
    else:
        yield path


def _check_not_moved(cls: type, raw: dict, prefix: str) -> None:
    """ConfigError for a key of ``raw`` that ``cls`` says has moved (:data:`MOVED`) or is derived (:data:`DERIVED`)."""
    moved = getattr(cls, MOVED, None)
    derived = getattr(cls, DERIVED, {})
    if moved is None and not derived:
        return
    for path in _leaf_paths(raw):
        dotted = ".".join(path)
        new = moved(dotted) if moved is not None else None
        if new:
            raise ConfigError(f"{prefix}{dotted}: moved to {new}")
        for i in range(1, len(path) + 1):
            if ".".join(path[:i]) in derived:
                raise ConfigError(f"{prefix}{dotted}: not a setting: derived from {derived['.'.join(path[:i])]}")


def _flattened(cls: type, hints: dict[str, Any]) -> dict[str, set[str]]:
    """The :data:`FLATTEN` fields of ``cls`` and the keys each takes from the section's own level."""
    return {
        f.name: {g.name for g in dataclasses.fields(hints[f.name])}
        for f in dataclasses.fields(cls)
        if f.metadata.get(FLATTEN)
    }


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """How a run executes. Only ``seed`` changes what is computed (and enters the keys, when not 0); the others
    change where and how fast, never a shard's bytes."""

    out: str = "out"
    """Output folder (relative to the current directory)."""
    jobs: int = 0
    """Worker processes; 0 means one per CPU core."""
    backend: Literal["loky", "dask", "ray"] = "loky"
    """joblib backend: ``loky`` (local processes), ``dask`` (a dask.distributed cluster) or ``ray``."""
    dask_address: str | None = None
    """Scheduler address for ``backend: dask`` (e.g. ``tcp://10.0.0.5:8786``); None starts a LocalCluster."""
    cache_dir: str = ".cache"
    """Folder for caches that survive ``gen clean`` (CoACD decompositions), relative to the current directory."""
    seed: int = 0
    """Seed of the whole dataset: another integer gives every task other random draws (another dataset), the same
    one the same bytes for any number of workers. It joins every task's seed key and content key only when not 0,
    so 0 keeps the keys and bytes of runs made before the setting existed; changing it makes every shard stale."""

    def __post_init__(self) -> None:
        if self.jobs < 0:
            raise ValueError(f"jobs: must be >= 0 (0 = all cores), got {self.jobs!r}")


# --------------------------------------------------------------------------------------------------------------
# Loading


def load_config(schema: type, path: str | Path | None = None, overrides: typing.Sequence[str] = ()) -> Any:
    """Load a YAML config file into the dataclass tree ``schema``.

    Parameters
    ----------
    schema : type
        A dataclass type whose fields are sections (dataclasses) or values; every field needs a default.
    path : str or Path, optional
        YAML file. None gives the defaults.
    overrides : sequence of str
        ``"key.path=value"`` strings, the value parsed as YAML, applied after the file.

    Returns
    -------
    An instance of ``schema``.

    Raises
    ------
    ConfigError
        Naming the file and the key path of the first problem found.
    """
    raw: dict[str, Any] = {}
    where = "defaults"
    if path is not None:
        path = Path(path)
        where = str(path)
        try:
            text = path.read_text()
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read config file ({exc.strerror or exc})") from None
        try:
            loaded = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise ConfigError(f"{path}: not valid YAML: {exc}") from None
        if loaded is None:
            loaded = {}
        if not isinstance(loaded, dict):
            raise ConfigError(f"{path}: the top level must be a mapping of sections, got {type(loaded).__name__}")
        raw = loaded
    for item in overrides:
        key, value = parse_override(item)
        _set_path(raw, key, value)
    try:
        return _build(schema, raw, "")
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def parse_override(item: str) -> tuple[list[str], Any]:
    """Split ``"a.b.c=value"`` into ``(["a", "b", "c"], yaml_value)``."""
    if "=" not in item:
        raise ConfigError(f"--set {item!r}: expected key.path=value")
    key, _, text = item.partition("=")
    parts = [p for p in key.strip().split(".")]
    if not all(parts):
        raise ConfigError(f"--set {item!r}: empty part in key path {key!r}")
    try:
        value = yaml.safe_load(text) if text.strip() else None
    except yaml.YAMLError as exc:
        raise ConfigError(f"--set {item!r}: value is not valid YAML: {exc}") from None
    return parts, value


def _set_path(raw: dict, parts: list[str], value: Any) -> None:
    node = raw
    for i, part in enumerate(parts[:-1]):
        child = node.get(part)
        if child is None:
            child = node[part] = {}
        if not isinstance(child, dict):
            raise ConfigError(f"--set {'.'.join(parts)}: {'.'.join(parts[: i + 1])} is not a section")
        node = child
    node[parts[-1]] = value


def _nested_default(f: dataclasses.Field, base: Any) -> Any:
    """What a nested section starts from: the enclosing default's value (``base``), else the field's
    ``default_factory`` (a section may default to other values than its class's), else None (the class's)."""
    if base is not None:
        return getattr(base, f.name)
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return f.default_factory()  # type: ignore[misc]
    return None


def _build(cls: type, raw: Any, prefix: str, base: Any = None) -> Any:
    """``cls`` from the mapping ``raw``; keys it does not set keep ``base``'s values (a default instance of ``cls``)
    or ``cls``'s defaults."""
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise ConfigError(f"{prefix.rstrip('.') or '(top level)'}: must be a mapping, got {raw!r}")
    _check_not_moved(cls, raw, prefix)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    flat = _flattened(cls, hints)
    valid = (set(fields) - set(flat)).union(*flat.values())
    unknown = sorted(set(raw) - valid)
    former = {old: name for name, f in fields.items() for old in f.metadata.get(RENAMED_FROM, ())}
    for key in unknown:
        if key in former:
            what = "section" if dataclasses.is_dataclass(hints[former[key]]) else "key"
            raise ConfigError(f"{prefix}{key}: {renamed_message(what, key, former[key])}")
    if unknown:
        key = unknown[0]
        raise ConfigError(f"{prefix}{key}: unknown key; valid keys: {', '.join(sorted(valid))}")
    kwargs = {}
    for name, f in fields.items():
        nested = _nested_default(f, base) if dataclasses.is_dataclass(hints[name]) else None
        if name in flat:
            kwargs[name] = _build(hints[name], {k: v for k, v in raw.items() if k in flat[name]}, prefix, nested)
        elif name in raw:
            _check_renamed_value(f, raw[name], f"{prefix}{name}")
            kwargs[name] = _convert(hints[name], raw[name], f"{prefix}{name}", nested)
        elif dataclasses.is_dataclass(hints[name]):
            kwargs[name] = _build(hints[name], {}, f"{prefix}{name}.", nested)
        elif base is not None:
            kwargs[name] = getattr(base, name)
    try:
        return cls(**kwargs)
    except ValueError as exc:
        raise ConfigError(f"{prefix}{exc}") from None
    except TypeError as exc:  # a field without a default that the file did not set
        raise ConfigError(f"{prefix.rstrip('.') or '(top level)'}: {exc}") from None


def _check_renamed_value(f: dataclasses.Field, value: Any, path: str) -> None:
    """ConfigError naming the new value when ``value`` is one the field's values were renamed from."""
    renamed = f.metadata.get(RENAMED_VALUES, {})
    if isinstance(value, str) and value in renamed:
        raise ConfigError(f"{path}: {renamed_message(f.name, value, renamed[value])}")


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(tp))
    if origin is tuple:
        return "a list"
    if origin is dict:
        return "a mapping"
    if tp is type(None):
        return "null"
    return getattr(tp, "__name__", str(tp))


def _convert(tp: Any, value: Any, path: str, base: Any = None) -> Any:
    """Check ``value`` against the annotation ``tp``; return it in the dataclass's own type (tuples, not lists);
    a dataclass section starts from ``base`` when given (:func:`_build`)."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    bad = ConfigError(f"{path}: must be {_type_name(tp)}, got {value!r}")
    if dataclasses.is_dataclass(tp):
        return _build(tp, value, f"{path}.", base)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        for arg in options:
            try:
                return _convert(arg, value, path)
            except ConfigError as exc:
                # A container's own error points inside it (e.g. ``sizes[1]``): more useful than the union's.
                if len(options) == 1 and typing.get_origin(arg) in (tuple, dict) or dataclasses.is_dataclass(arg):
                    raise exc
        raise bad
    if origin is Literal:
        if value in args:
            return value
        raise ConfigError(f"{path}: must be {_type_name(tp)}, got {value!r}")
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise bad
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{path}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{path}: must be a list of {len(args)} values, got {value!r}")
        return tuple(_convert(a, v, f"{path}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
    if origin is dict:
        if not isinstance(value, dict):
            raise bad
        key_t, val_t = args
        return types.MappingProxyType(
            {_convert(key_t, k, path): _convert(val_t, v, f"{path}.{k}") for k, v in sorted(value.items())}
        )
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise bad
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise bad
    if tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise bad
    if tp is str:
        if isinstance(value, str):
            return value
        raise bad
    if tp is Any:
        return value
    raise TypeError(f"{path}: unsupported annotation {tp!r} in the config schema")


# --------------------------------------------------------------------------------------------------------------
# Showing


def to_dict(obj: Any) -> Any:
    """Plain-Python (JSON/YAML-able) form of a config tree: dataclasses -> dicts, tuples -> lists."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        out: dict[str, Any] = {}
        for f in dataclasses.fields(obj):
            value = to_dict(getattr(obj, f.name))
            if f.metadata.get(FLATTEN):
                out.update(value)
            else:
                out[f.name] = value
        return out
    if isinstance(obj, (tuple, list)):
        return [to_dict(v) for v in obj]
    if isinstance(obj, (dict, types.MappingProxyType)):
        return {str(k): to_dict(v) for k, v in obj.items()}
    return obj


def field_docs(cls: type) -> dict[str, str]:
    """The attribute docstrings of a dataclass (the string literal under each field), by field name; a subclass's
    over those of the dataclasses it derives from."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if dataclasses.is_dataclass(klass):
            docs.update(_own_field_docs(klass))
    return docs


def _own_field_docs(cls: type) -> dict[str, str]:
    """The attribute docstrings written in the body of ``cls`` itself."""
    import ast
    import inspect
    import textwrap

    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    tree = ast.parse(source)
    docs: dict[str, str] = {}
    body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
    for stmt, nxt in zip(body, body[1:]):
        if (
            isinstance(stmt, ast.AnnAssign)
            and isinstance(stmt.target, ast.Name)
            and isinstance(nxt, ast.Expr)
            and isinstance(nxt.value, ast.Constant)
            and isinstance(nxt.value.value, str)
        ):
            docs[stmt.target.id] = " ".join(nxt.value.value.split())
    return docs


def to_yaml(obj: Any, *, comments: bool = True, defaults: Any = None) -> str:
    """YAML text of a config tree, each key preceded by its field docstring as a comment; derived keys (a section's
    :data:`DERIVED`) left out. With ``defaults`` (a tree of the same schema), only the keys whose values differ from
    it, in the sections that hold one."""
    out = io.StringIO()
    _emit_yaml(obj, out, 0, comments, frozenset(), defaults if defaults is not None else _EVERY)
    return out.getvalue()


_EVERY = object()
"""``_emit_yaml``'s ``defaults`` when every key is written."""


def _emit_yaml(obj: Any, out: io.StringIO, indent: int, comments: bool, skip: frozenset[str], defaults: Any) -> None:
    docs = field_docs(type(obj)) if comments else {}
    pad = "  " * indent
    skip = skip | set(getattr(type(obj), DERIVED, {}))
    for f in dataclasses.fields(obj):
        if f.name in skip:
            continue
        value = getattr(obj, f.name)
        default = _EVERY if defaults is _EVERY or defaults is None else getattr(defaults, f.name)
        inner = frozenset(p.removeprefix(f"{f.name}.") for p in skip if p.startswith(f"{f.name}."))
        if f.metadata.get(FLATTEN):
            _emit_yaml(value, out, indent, comments, inner, default)
            continue
        if dataclasses.is_dataclass(value):
            body = io.StringIO()
            _emit_yaml(value, body, indent + 1, comments, inner, default)
            text = f"{pad}{f.name}:\n{body.getvalue()}" if body.getvalue() or default is _EVERY else ""
        elif default is _EVERY or to_dict(value) != to_dict(default):
            flow = yaml.safe_dump({f.name: to_dict(value)}, default_flow_style=True, sort_keys=False, width=1000)
            text = f"{pad}{flow.strip()[1:-1]}\n"  # drop the braces of the one-key flow mapping
        else:
            text = ""
        if text and f.name in docs:
            out.write(f"{pad}# {docs[f.name]}\n")
        out.write(text)
