"""Content keys and per-task randomness."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.keys import canonical_json, key_parts, rng_for_key, task_key


@dataclasses.dataclass(frozen=True)
class P:
    a: float = 1.0
    b: tuple[int, ...] = (1, 2)


def parts(**change):
    base = dict(stage="s", version=1, params=P(), task_id="t", payload={}, upstream={}, input_hashes={})
    base.update(change)
    return key_parts(**base)


def test_canonical_json_ignores_dict_order():
    assert canonical_json({"b": 1, "a": [1, 2.5]}) == canonical_json({"a": (1, 2.5), "b": 1}) == '{"a":[1,2.5],"b":1}'
    with pytest.raises(ValueError, match="non-finite"):
        canonical_json({"x": float("nan")})


def test_every_component_changes_the_key():
    ref = task_key(parts())
    assert task_key(parts()) == ref
    changed = [
        parts(version=2),
        parts(params=P(a=2.0)),
        parts(task_id="u"),
        parts(payload={"x": 1}),
        parts(upstream={"up": {"t": "k"}}),
        parts(input_hashes={"0": "ff"}),
    ]
    assert len({task_key(p) for p in changed} | {ref}) == len(changed) + 1


def test_rng_is_a_pure_function_of_the_key():
    key = task_key(parts())
    assert np.array_equal(rng_for_key(key).random(5), rng_for_key(key).random(5))
    other = task_key(parts(task_id="other"))
    assert not np.array_equal(rng_for_key(key).random(5), rng_for_key(other).random(5))


def test_a_field_flagged_key_omit_default_leaves_the_key_alone_at_its_default():
    import dataclasses

    from pipeline.keys import KEY_OMIT_DEFAULT, canonical_json

    @dataclasses.dataclass(frozen=True)
    class Before:
        a: int = 1

    @dataclasses.dataclass(frozen=True)
    class After:
        a: int = 1
        added: tuple | None = dataclasses.field(default=None, metadata={KEY_OMIT_DEFAULT: True})
        plain: int | None = None

    assert canonical_json(After()) == '{"a":1,"plain":null}'
    assert canonical_json(After(added=(2, 3))) == '{"a":1,"added":[2,3],"plain":null}'

    @dataclasses.dataclass(frozen=True)
    class Omitting:
        a: int = 1
        added: int | None = dataclasses.field(default=None, metadata={KEY_OMIT_DEFAULT: True})

    assert canonical_json(Omitting()) == canonical_json(Before())
    assert canonical_json({"s": Omitting(added=4)}) == '{"s":{"a":1,"added":4}}'


def test_a_renamed_field_or_value_is_hashed_as_it_was_named():
    from shared_utils.keys import KEY_NAME, KEY_VALUES, key_view

    @dataclasses.dataclass(frozen=True)
    class Before:
        mode: str = "old"
        old_name: int = 1

    @dataclasses.dataclass(frozen=True)
    class After:
        mode: str = dataclasses.field(default="new", metadata={KEY_VALUES: {"new": "old"}})
        new_name: int = dataclasses.field(default=1, metadata={KEY_NAME: "old_name"})

    assert canonical_json(After()) == canonical_json(Before())
    assert key_view(After()) == dataclasses.asdict(Before())
    assert canonical_json(After(mode="other")) == canonical_json(Before(mode="other"))


def test_the_graspdatagen_rename_keeps_the_keys_and_draws():
    """The protocol and its section were called ``graspgen`` when datasets were made: keys and seeds hash them so."""
    from graspgen.sim.protocols import LiftParams
    from graspgen.workflows.object_grasps_settings import ObjectGraspsParams
    from shared_utils.keys import key_view

    lift = canonical_json(LiftParams(protocol="graspdatagen"))
    assert '"graspgen":{' in lift and '"protocol":"graspgen"' in lift and "graspdatagen" not in lift
    assert '"protocol":"graspgen"' in canonical_json(ObjectGraspsParams(protocol="graspdatagen"))
    view = key_view(LiftParams(protocol="graspdatagen"))
    old = LiftParams(protocol="graspdatagen").to_dict()
    old["graspgen"], old["protocol"] = old.pop("graspdatagen"), "graspgen"
    assert view == old  # gen evaluate's robustness seed (content_seed) hashes this view
