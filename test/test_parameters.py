"""Parameter validation and the shipped params files."""

import math

import numpy as np
import pytest
import yaml

from cr_control.core.parameters import Param, ParameterError, resolve, validate
from cr_control.core.paths import config_file
from cr_control.schemes.registry import SCHEMES, controller_class
from cr_control.tools.config_files import params_yaml, plant_yaml, robot_files

GAIN = Param("Q", [5.0, 5.0], "a positive definite gain", "spd", 2)
NEG = Param("D", [-2.0, -2.0], "a negative definite matrix", "nd", 2)


def test_diagonal_and_full_forms_mean_the_same():
    assert np.array_equal(validate(GAIN, [5.0, 5.0])[2], validate(GAIN, [5.0, 0.0, 0.0, 5.0])[2])


@pytest.mark.parametrize("value,reason", [
    ([1.0, 2.0, 3.0], "needs 2"),
    ([math.nan, 1.0], "finite"),
    ([math.inf, 1.0], "finite"),
    ([-1.0, 5.0], "positive definite"),
    ([1.0, 2.0, 2.0, 1.0], "positive definite"),   # symmetric, eigenvalues -1 and 3
    ([1.0, 2.0, 0.0, 1.0], "symmetric"),
    ("fast", "list of numbers"),
])
def test_bad_gains_are_refused_with_a_reason(value, reason):
    ok, why, converted = validate(GAIN, value)
    assert not ok and reason in why and converted is None


def test_negative_definite_kind():
    assert validate(NEG, [-2.0, -3.0])[0]
    assert not validate(NEG, [2.0, -3.0])[0]


def test_scalar_kinds():
    positive = Param("k", 1.0, "gain", "positive")
    assert validate(positive, 3)[0] and not validate(positive, 0.0)[0]
    assert not validate(positive, True)[0] and not validate(positive, math.nan)[0]


def test_resolve_rejects_unknown_and_bad_overrides():
    with pytest.raises(ParameterError, match="unknown"):
        resolve([GAIN], {"Qx": [1.0, 1.0]})
    with pytest.raises(ParameterError, match="positive definite"):
        resolve([GAIN], {"Q": [0.0, 1.0]})


@pytest.mark.parametrize("scheme", sorted(SCHEMES))
def test_shipped_controller_config_is_the_thesis_defaults(scheme):
    path = config_file(f"{scheme}.yaml")
    assert path.read_text() == params_yaml(scheme)
    values = yaml.safe_load(path.read_text())[scheme]["ros__parameters"]
    for param in controller_class(scheme).parameters():
        assert values[param.name] == param.ros_default
        assert type(values[param.name]) is type(param.ros_default)


@pytest.mark.parametrize("name", sorted(robot_files()))
def test_shipped_robot_configs_are_the_generated_wiping_task(name):
    """config/robots/<robot>/*.yaml (cr_session --robot) are what the generator writes."""
    assert config_file(name).read_text() == robot_files()[name]


def test_shipped_plant_config_is_the_defaults():
    assert config_file("plant_compliant_plane.yaml").read_text() == plant_yaml("compliant_plane")


def test_adaptive_impedance_defaults_are_section_3_5_1():
    v = resolve(controller_class("adaptive_impedance").parameters())
    assert np.array_equal(v["A_m"], 20 * np.eye(2)) and np.array_equal(v["B_m"], 400 * np.eye(2))
    assert np.array_equal(v["P1"], 1.25 * np.eye(2)) and np.array_equal(v["P2"], 6.56 * np.eye(2))
    assert np.array_equal(v["A_hat_0"], 45 * np.eye(2)) and np.array_equal(v["B_hat_0"], 30 * np.eye(2))
    assert np.array_equal(v["c_hat_0"], [1.0, 1.0])
    for name in ("Q_a", "Q_b", "Q_c", "Q_a_star"):
        assert np.array_equal(v[name], 5 * np.eye(2))
    for name in ("Q_b_star", "Q_c_star"):
        assert np.array_equal(v[name], 1.5 * np.eye(2))
    assert np.array_equal(v["desired_force"], [5.0, -5.0])
