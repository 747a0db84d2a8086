"""The shared argument and settings checks of graspgen.validation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graspgen.errors import GraspGenError, SettingsError
from graspgen.validation import (
    POSE_TOL,
    check,
    check_bool,
    check_choice,
    check_instance,
    check_int,
    check_number,
    check_positive_int,
    check_range,
    check_rng,
    check_transform,
    check_transforms,
    check_vector,
)


def pose(angles=(0.3, -1.0, 2.0), t=(0.1, -0.2, 0.3)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", angles).as_matrix()
    T[:3, 3] = t
    return T


def test_errors_are_settings_errors_and_value_errors():
    with pytest.raises(SettingsError) as err:
        check_number("x", "a")
    assert isinstance(err.value, ValueError) and isinstance(err.value, GraspGenError)


def test_check():
    check("x", True, "be fine", 1)
    with pytest.raises(SettingsError, match=r"^x: must be > 0, got -1$"):
        check("x", False, "be > 0", -1)


# ------------------------------------------------------------------------------------------------------- numbers


@pytest.mark.parametrize("value", [0.5, 1, np.float32(0.25), np.int64(3), np.float64(2.0), np.array(0.5)])
def test_number_accepts_real_scalars_and_returns_a_float(value):
    out = check_number("friction", value)
    assert type(out) is float and out == float(value)


@pytest.mark.parametrize("value", [True, np.bool_(False), "0.5", None, [0.5], np.array([0.5]), 1 + 2j])
def test_number_rejects_non_numbers_and_bools(value):
    with pytest.raises(SettingsError, match=r"^friction: must be a number, got "):
        check_number("friction", value)


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, np.float64("nan")])
def test_number_rejects_nan_and_infinity(value):
    with pytest.raises(SettingsError, match=r"^friction: must be finite, got "):
        check_number("friction", value)


@pytest.mark.parametrize(
    "kwargs, good, bad, interval",
    [
        (dict(low=0.0), [0.0, 5.0], [-1e-9], r"\[0, inf\)"),
        (dict(low=0.0, low_open=True), [1e-12], [0.0, -1.0], r"\(0, inf\)"),
        (dict(high=1.0), [-5.0, 1.0], [1.5], r"\(-inf, 1\]"),
        (dict(low=0.0, high=1.0), [0.0, 0.5, 1.0], [-0.1, 1.1], r"\[0, 1\]"),
        (dict(low=0.0, high=math.pi / 2, low_open=True, high_open=True), [0.1], [0.0, math.pi / 2], r"\(0, 1.5708\)"),
    ],
)
def test_number_bounds_in_interval_notation(kwargs, good, bad, interval):
    for value in good:
        assert check_number("angle", value, **kwargs) == value
    for value in bad:
        with pytest.raises(SettingsError, match=rf"^angle: must be in {interval}, got {value!r}"):
            check_number("angle", value, **kwargs)


def test_int():
    assert check_int("n", 3) == 3 and type(check_int("n", np.int32(3))) is int
    assert check_int("n", 0, low=0) == 0 and check_int("n", 30, low=1, high=30) == 30
    for value in (2.0, 2.5, True, np.bool_(True), "3", None, math.nan):
        with pytest.raises(SettingsError, match=r"^n: must be an integer, got "):
            check_int("n", value)
    with pytest.raises(SettingsError, match=r"^n: must be an integer in \[1, inf\), got 0$"):
        check_int("n", 0, low=1)
    with pytest.raises(SettingsError, match=r"^n: must be an integer in \[1, 30\], got 31$"):
        check_int("n", 31, low=1, high=30)


def test_positive_int():
    assert check_positive_int("rays", 1) == 1 and type(check_positive_int("rays", np.int64(4))) is int
    for value in (0, -1, 2.0, True, "1", None):
        with pytest.raises(SettingsError, match=r"^rays: must be a positive integer, got "):
            check_positive_int("rays", value)


def test_bool():
    assert check_bool("shake", True) is True and check_bool("shake", np.bool_(False)) is False
    for value in (1, 0, "true", None, math.nan):
        with pytest.raises(SettingsError, match=r"^shake: must be a bool, got "):
            check_bool("shake", value)


def test_rng():
    rng = np.random.default_rng(0)
    assert check_rng("rng", rng) is rng
    for value in (0, np.random.RandomState(0), None):
        with pytest.raises(SettingsError, match=r"^rng: must be a numpy.random.Generator, got "):
            check_rng("rng", value)


def test_instance_and_choice():
    assert check_instance("params", 1.5, float) == 1.5
    with pytest.raises(SettingsError, match=r"^params: must be a float, got str$"):
        check_instance("params", "x", float)
    with pytest.raises(SettingsError, match=r"^params: must be an int, got str$"):
        check_instance("params", "x", int)
    assert check_choice("cone", "elliptic", ("elliptic", "pyramidal")) == "elliptic"
    with pytest.raises(SettingsError, match=r"^cone: must be one of elliptic, pyramidal, got 'round'$"):
        check_choice("cone", "round", ("elliptic", "pyramidal"))
    with pytest.raises(SettingsError, match=r"^cone: must be one of a, b, got \['a'\]$"):
        check_choice("cone", ["a"], ("a", "b"))
    with pytest.raises(SettingsError, match=r"^cone: must be one of"):
        check_choice("cone", ["a"], {"a": 1})  # unhashable against a dict: not a TypeError


def test_vector():
    assert check_vector("size", [0.1, 0.2, 0.3], 3, low=0.0, low_open=True) == (0.1, 0.2, 0.3)
    assert check_vector("pos", np.zeros((1, 3)), 3) == (0.0, 0.0, 0.0)
    for value in ([0.1, 0.2], [0.1, math.nan, 0.3], "abc", [[1, 2], [3]], None):
        with pytest.raises(SettingsError, match=r"^size: must be 3 finite numbers, got "):
            check_vector("size", value, 3)
    with pytest.raises(SettingsError, match=r"^size: every entry must be in \(0, inf\), got "):
        check_vector("size", (0.1, 0.0, 0.3), 3, low=0.0, low_open=True)
    assert check_vector("friction", (0.5, 0.0, 0.0), 3, low=0.0) == (0.5, 0.0, 0.0)


def test_range():
    assert check_range("distance", (0.5, 0.8), low=1e-3) == (0.5, 0.8)
    assert check_range("roll", [0, 0], low=-math.pi, high=math.pi) == (0.0, 0.0)
    for value in ((0.8, 0.5), (0.5,), (0.1, 0.2, 0.3), 0.5, ("a", "b"), (True, True), (math.nan, 1.0)):
        with pytest.raises(SettingsError, match=r"^distance: must be \[min, max\] with min <= max, got "):
            check_range("distance", value, low=1e-3)
    with pytest.raises(SettingsError, match=r"^elevation: must lie in \[-1.5708, 1.5708\], got \(0.2, 2.0\)$"):
        check_range("elevation", (0.2, 2.0), low=-math.pi / 2, high=math.pi / 2)
    with pytest.raises(SettingsError, match=r"^distance: must lie in \[0.001, inf\), got \(0, 1\)$"):
        check_range("distance", (0, 1), low=1e-3)


# ------------------------------------------------------------------------------------------------------- poses


def test_transform_accepts_rigid_poses_and_float32_round_off():
    T = pose()
    assert check_transform("pose", T) is T  # no copy
    stored = T.astype(np.float32)  # orthonormal only to ~1e-7 per entry
    out = check_transform("pose", stored)
    assert out.dtype == np.float64 and out.shape == (4, 4)
    check_transform("pose", T.tolist())
    nearly = T.copy()
    nearly[:3, :3] *= 1 + POSE_TOL / 4
    check_transform("pose", nearly)


@pytest.mark.parametrize(
    "value, message",
    [
        (np.eye(3), r"^pose: must have shape \(4, 4\), got shape \(3, 3\)$"),
        (np.eye(4)[None], r"^pose: must have shape \(4, 4\), got shape \(1, 4, 4\)$"),
        ([[1, 2], [3]], r"^pose: must be an array of 4x4 rigid transforms, got "),
        (np.full((4, 4), np.nan), r"^pose: must be finite$"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), r"^pose: the rotation block is not a proper rotation \(orthonormal to 1e-05"),
        (np.diag([2.0, 2.0, 2.0, 1.0]), r"^pose: the rotation block is not a proper rotation"),
        (np.diag([1.0, 1.0, 1.0, 2.0]), r"^pose: the last row must be 0 0 0 1$"),
    ],
)
def test_transform_rejects_wrong_shape_nan_improper_rotation_and_last_row(value, message):
    with pytest.raises(SettingsError, match=message):
        check_transform("pose", value)


def test_transform_tolerance():
    T = pose()
    T[0, 1] += 3 * POSE_TOL  # sheared beyond the tolerance
    with pytest.raises(SettingsError, match="rotation block"):
        check_transform("pose", T)


def test_transforms_stacks():
    T = np.stack([pose(), pose((0.1, 0.2, 0.3)), np.eye(4)])
    assert check_transforms("T_tcp", T) is T
    assert check_transforms("T_tcp", np.zeros((0, 4, 4))).shape == (0, 4, 4)
    assert check_transforms("T_tcp", T.astype(np.float32)).dtype == np.float64
    single = check_transforms("T_tcp", pose(), allow_single=True)
    assert single.shape == (1, 4, 4)
    with pytest.raises(SettingsError, match=r"^T_tcp: must have shape \(n, 4, 4\), got shape \(4, 4\)$"):
        check_transforms("T_tcp", pose())
    with pytest.raises(SettingsError, match=r"^T_tcp: must have shape \(4, 4\) or \(n, 4, 4\), got shape \(3, 3\)$"):
        check_transforms("T_tcp", np.eye(3), allow_single=True)
    with pytest.raises(SettingsError, match=r"^T_tcp: must have shape \(n, 4, 4\), got shape \(2, 3, 4\)$"):
        check_transforms("T_tcp", np.zeros((2, 3, 4)))


def test_transforms_name_the_first_bad_one_and_count_them():
    T = np.stack([pose(), np.diag([1.0, 1.0, -1.0, 1.0]), pose(), np.diag([1.0, -1.0, 1.0, 1.0])])
    with pytest.raises(SettingsError, match=r"^T_tcp\[1\]: the rotation block is not a proper rotation .*\(2 of 4 "
                                            r"transforms\)$"):
        check_transforms("T_tcp", T)
    T = np.stack([pose(), pose()])
    T[1, 2, 3] = math.inf
    with pytest.raises(SettingsError, match=r"^T_tcp\[1\]: must be finite \(1 of 2 transforms\)$"):
        check_transforms("T_tcp", T)
    T = np.stack([pose(), pose()])
    T[0, 3, 0] = 0.5
    with pytest.raises(SettingsError, match=r"^T_tcp\[0\]: the last row must be 0 0 0 1 \(1 of 2 transforms\)$"):
        check_transforms("T_tcp", T)
