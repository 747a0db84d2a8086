"""Config loading: types, ranges, unknown keys and overrides are checked up front, naming the key path."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import ClassVar, Literal

import pytest
import yaml

from graspgen.validation import check
from pipeline.config import RunConfig, field_docs, load_config, to_dict, to_yaml
from pipeline.errors import ConfigError
from shared_utils.renames import RENAMED_FROM, RENAMED_VALUES


@dataclasses.dataclass(frozen=True)
class Inner:
    friction: float = 0.5
    """Coulomb friction coefficient."""
    mode: Literal["above", "any"] = "above"
    """Approach filter."""
    sizes: tuple[float, float] = (0.1, 0.2)
    """A range, m."""

    def __post_init__(self) -> None:
        check("friction", self.friction > 0, "be > 0", self.friction)


@dataclasses.dataclass(frozen=True)
class Root:
    run: RunConfig = dataclasses.field(default_factory=RunConfig)
    grasps: Inner = dataclasses.field(default_factory=Inner)
    names: tuple[str, ...] = ()
    limit: int | None = None
    table: dict[str, float] = dataclasses.field(default_factory=dict)


def write(tmp_path, data) -> str:
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_defaults_without_file():
    cfg = load_config(Root)
    assert cfg == Root()


def test_file_values_are_typed(tmp_path):
    cfg = load_config(Root, write(tmp_path, {"grasps": {"friction": 1, "sizes": [0.05, 0.3]}, "names": ["a", "b"]}))
    assert cfg.grasps.friction == 1.0 and isinstance(cfg.grasps.friction, float)
    assert cfg.grasps.sizes == (0.05, 0.3)
    assert cfg.names == ("a", "b")


@pytest.mark.parametrize(
    "data, message",
    [
        ({"grasps": {"frction": 1}}, "grasps.frction: unknown key; valid keys: friction, mode, sizes"),
        ({"grasps": {"friction": -1}}, "grasps.friction: must be > 0, got -1.0"),
        ({"grasps": {"friction": "high"}}, "grasps.friction: must be float, got 'high'"),
        ({"grasps": {"mode": "below"}}, "grasps.mode: must be one of 'above', 'any', got 'below'"),
        ({"grasps": {"sizes": [1]}}, "grasps.sizes: must be a list of 2 values"),
        ({"limit": 1.5}, "limit: must be int or null, got 1.5"),
        ({"limit": True}, "limit: must be int or null, got True"),
        ({"table": {"a": "x"}}, "table.a: must be float"),
        ({"run": {"jobs": -2}}, "run.jobs: must be >= 0"),
        ({"run": {"backend": "spark"}}, "run.backend: must be one of 'loky', 'dask', 'ray'"),
        ({"grasps": 3}, "grasps: must be a mapping"),
        ({"wat": 1}, "wat: unknown key"),
    ],
)
def test_errors_name_the_key_path(tmp_path, data, message):
    path = write(tmp_path, data)
    with pytest.raises(ConfigError) as err:
        load_config(Root, path)
    assert message in str(err.value)
    assert str(err.value).startswith(path)


def test_overrides_parse_yaml_and_win(tmp_path):
    path = write(tmp_path, {"grasps": {"friction": 0.3}})
    cfg = load_config(Root, path, ["grasps.friction=0.9", "names=[x, y]", "limit=null", "run.out=/tmp/o"])
    assert cfg.grasps.friction == 0.9
    assert cfg.names == ("x", "y")
    assert cfg.limit is None
    assert cfg.run.out == "/tmp/o"


@pytest.mark.parametrize("item, message", [("grasps.friction", "expected key.path=value"), ("a..b=1", "empty part")])
def test_bad_override_syntax(item, message):
    with pytest.raises(ConfigError, match=message):
        load_config(Root, None, [item])


def test_override_of_unknown_key_is_an_error():
    with pytest.raises(ConfigError, match="grasps.nope: unknown key"):
        load_config(Root, None, ["grasps.nope=1"])


def test_bad_yaml_and_missing_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("grasps: [unclosed")
    with pytest.raises(ConfigError, match="bad.yaml: not valid YAML"):
        load_config(Root, bad)
    with pytest.raises(ConfigError, match="nope.yaml: cannot read config file"):
        load_config(Root, tmp_path / "nope.yaml")
    top = tmp_path / "list.yaml"
    top.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="top level must be a mapping"):
        load_config(Root, top)


def test_yaml_round_trip_with_docs(tmp_path):
    cfg = load_config(Root, None, ["grasps.friction=0.7", "table={b: 2, a: 1}"])
    text = to_yaml(cfg)
    assert "# Coulomb friction coefficient." in text
    reloaded = load_config(Root, write(tmp_path, yaml.safe_load(text)))
    assert to_dict(reloaded) == to_dict(cfg)
    assert field_docs(Inner)["sizes"] == "A range, m."


@dataclasses.dataclass(frozen=True)
class Outer:
    free_space: Inner = dataclasses.field(default_factory=lambda: Inner(friction=1.0, mode="any"))
    """A section whose default is not its class's."""
    table_top: Inner = dataclasses.field(default_factory=Inner)


def test_a_section_starts_from_its_fields_default_not_its_classs(tmp_path):
    assert load_config(Outer) == Outer()  # friction 1.0, mode any: the field's default
    cfg = load_config(Outer, write(tmp_path, {"free_space": {"sizes": [0.0, 0.3]}}))
    assert cfg.free_space == Inner(friction=1.0, mode="any", sizes=(0.0, 0.3))  # the unset keys keep the default
    assert cfg.table_top == Inner()
    cfg = load_config(Outer, write(tmp_path, {"free_space": {"mode": "above"}}), ["table_top.friction=2"])
    assert cfg.free_space == Inner(friction=1.0, mode="above") and cfg.table_top == Inner(friction=2.0)


@dataclasses.dataclass(frozen=True)
class Renamed:
    mode: Literal["above", "any"] = dataclasses.field(default="above", metadata={RENAMED_VALUES: {"up": "above"}})
    """Approach filter (``up`` was its old name for ``above``)."""
    inner: Inner = dataclasses.field(default_factory=Inner, metadata={RENAMED_FROM: ("old_inner",)})
    """A section once called ``old_inner``."""
    count: int = dataclasses.field(default=1, metadata={RENAMED_FROM: ("n",)})
    """A key once called ``n``."""


@dataclasses.dataclass(frozen=True)
class RenamedRoot:
    s: Renamed = dataclasses.field(default_factory=Renamed)


@pytest.mark.parametrize("override, message", [
    ("s.mode=up", "s.mode: mode 'up' was renamed 'above'"),
    ("s.old_inner.friction=1.0", "s.old_inner: section 'old_inner' was renamed 'inner'"),
    ("s.n=2", "s.n: key 'n' was renamed 'count'"),
    ("s.nope=2", "s.nope: unknown key; valid keys: count, inner, mode"),
])
def test_a_renamed_key_or_value_is_answered_with_its_new_name(override, message):
    with pytest.raises(ConfigError, match=f"^defaults: {message}$"):
        load_config(RenamedRoot, None, [override])
    assert load_config(RenamedRoot, None, ["s.mode=any", "s.count=3"]).s == Renamed(mode="any", count=3)


@dataclasses.dataclass(frozen=True)
class Base:
    width: float = 0.02
    """Opening margin (m)."""
    inner: Inner = dataclasses.field(default_factory=Inner)
    """A section."""


@dataclasses.dataclass(frozen=True)
class Derived(Base):
    config_derived: ClassVar[dict[str, str]] = {"width": "top.width", "inner.friction": "top.width"}
    config_moved: ClassVar[Callable[[str], str | None]] = staticmethod(
        lambda path: "top.width" if path == "old.width" else None)
    extra: int = 1
    """A key the subclass adds."""


@dataclasses.dataclass(frozen=True)
class DerivedRoot:
    width: float = 0.02
    """The one opening margin (m)."""
    s: Derived = dataclasses.field(default_factory=Derived)


@pytest.mark.parametrize("override, message", [
    ("s.width=0.03", "s.width: not a setting: derived from top.width"),
    ("s.inner.friction=2", "s.inner.friction: not a setting: derived from top.width"),
    ("s.old.width=0.03", "s.old.width: moved to top.width"),
])
def test_a_derived_or_moved_key_names_where_it_comes_from(override, message):
    with pytest.raises(ConfigError, match=f"^defaults: {message}$"):
        load_config(DerivedRoot, None, [override])
    assert load_config(DerivedRoot, None, ["s.inner.mode=above"]).s.inner.mode == "above"


def test_to_yaml_leaves_derived_keys_out_and_shows_what_differs():
    cfg = load_config(DerivedRoot, None, ["s.extra=2"])
    every = to_yaml(cfg)
    assert "# A key the subclass adds." in every and "# Opening margin (m)." not in every  # docs of the bases too
    assert "friction" not in every
    assert yaml.safe_load(every) == {"width": 0.02, "s": {"inner": {"mode": "above", "sizes": [0.1, 0.2]}, "extra": 2}}
    assert yaml.safe_load(to_yaml(cfg, defaults=DerivedRoot())) == {"s": {"extra": 2}}
    assert to_yaml(DerivedRoot(), defaults=DerivedRoot()) == ""
