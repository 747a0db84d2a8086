"""Every settings class of the library rejects a bool, an infinite or NaN number, and a fractional count, with a
:class:`~graspgen.errors.SettingsError` that names the field.

The classes are found by walking the package (every frozen dataclass of ``graspgen`` with a ``__post_init__``
that can be built from its defaults), so a new settings class is covered without being listed here."""

from __future__ import annotations

import dataclasses
import importlib
import math
import pkgutil

import pytest

import graspgen
from graspgen.errors import SettingsError

_OPTIONAL_EXTRAS = ("graspgen.learn", "graspgen.sim.warp")


def _modules():
    for info in pkgutil.walk_packages(graspgen.__path__, "graspgen."):
        try:
            yield importlib.import_module(info.name)
        except ImportError:
            if not info.name.startswith(_OPTIONAL_EXTRAS):
                raise


def _settings_classes() -> list[type]:
    found = {}
    for module in _modules():
        for value in vars(module).values():
            if (isinstance(value, type) and dataclasses.is_dataclass(value) and value.__module__ == module.__name__
                    and value.__dataclass_params__.frozen and hasattr(value, "__post_init__")):
                try:
                    value()
                except TypeError:  # needs arguments: a record, not a settings class
                    continue
                found[f"{value.__module__}.{value.__qualname__}"] = value
    return [found[name] for name in sorted(found)]


def _number_fields(cls: type) -> list[tuple[str, str]]:
    """(field name, "int" or "float") of the fields whose default is a plain number."""
    instance = cls()
    out = []
    for field in dataclasses.fields(cls):
        default = getattr(instance, field.name)
        if isinstance(default, bool) or not isinstance(default, (int, float)):
            continue
        annotation = str(field.type).replace(" ", "")
        kind = "int" if annotation.split("|")[0] == "int" else "float"
        out.append((field.name, kind))
    return out


_CASES = [(cls, name, kind) for cls in _settings_classes() for name, kind in _number_fields(cls)]


def test_walk_finds_the_settings_classes():
    names = {cls.__name__ for cls, _, _ in _CASES}
    assert {"LiftParams", "RobustnessParams", "ScenesParams", "GraspsParams"} <= names


@pytest.mark.parametrize(("cls", "field", "kind"), _CASES,
                         ids=[f"{cls.__name__}.{field}" for cls, field, _ in _CASES])
def test_bad_numbers_raise_a_settings_error_naming_the_field(cls, field, kind):
    bad = [True, math.inf, math.nan] + ([2.5] if kind == "int" else [])
    for value in bad:
        with pytest.raises(SettingsError) as caught:
            cls(**{field: value})
        assert field in str(caught.value), f"{cls.__name__}({field}={value!r}): {caught.value}"
