"""Configuration: bad values are rejected naming the key; the FEM sections build the problem."""

import pytest

from granular_multiscale.config import CONFIG_DIR, ConfigError, load_config, validate_config
from granular_multiscale.fem.triaxial import TriaxialProblem


@pytest.mark.parametrize(
    "config, key",
    [
        ({"dem": {"n_spheres": -5}}, "dem.n_spheres"),
        ({"training_path": "path9"}, "training_path"),
        ({"newton": {"max_iterations": "ten"}}, "newton.max_iterations"),
        ({"specimen": {"elements": [2, 2]}}, "specimen.elements"),
        ({"specimen": {"platen": "sticky"}}, "specimen.platen"),
        ({"elastoplastic": {"friction": -0.1}}, "elastoplastic.friction"),
        ({"elastoplastic": {"kinematic_modulus": "stiff"}}, "elastoplastic.kinematic_modulus"),
        ({"elastoplastic": {"cohesion": 1.0}}, "elastoplastic"),
    ],
)
def test_bad_config_is_rejected_naming_the_key(config, key):
    with pytest.raises(ConfigError) as error:
        validate_config(config)
    assert f"'{key}'" in str(error.value)


def test_load_config_override_with_wrong_type_names_the_key():
    with pytest.raises(ConfigError, match=r"'specimen\.confining_pressure'"):
        load_config(CONFIG_DIR / "tiny.yaml", overrides={"specimen.confining_pressure": "high"})


@pytest.mark.parametrize("name, n_gp", [("tiny.yaml", 16), ("config.yaml", 128), ("paper.yaml", 2000), ("elastoplastic.yaml", 128)])
def test_shipped_configs_build_the_triaxial_problem(name, n_gp):
    problem = TriaxialProblem.from_config(load_config(CONFIG_DIR / name))
    assert problem.n_gauss_points == n_gp
    assert problem.confining_pressure == 1.0e5


def test_numbers_given_as_strings_are_read_as_numbers():
    """YAML 1.1 reads `1e-4` as a string, and Snakemake's --config 'analysis={...: [100, 300]}'
    gives the nested values as strings: both are read as the numbers (booleans) they are; words are not."""
    config = validate_config({"surrogate": {"learning_rate": "1e-4", "anchor_initial_state": "false"},
                              "analysis": {"fem_dem_sphere_counts": ["100", "300"]}})
    assert config["surrogate"]["learning_rate"] == 1e-4
    assert config["surrogate"]["anchor_initial_state"] is False
    with pytest.raises(ConfigError, match=r"'surrogate\.anchor_initial_state'"):
        validate_config({"surrogate": {"anchor_initial_state": "maybe"}})
    assert config["analysis"]["fem_dem_sphere_counts"] == [100, 300]
    with pytest.raises(ConfigError, match=r"'analysis\.fem_dem_sphere_counts\[0\]'"):
        validate_config({"analysis": {"fem_dem_sphere_counts": ["many"]}})


def test_fem_ml_newton_overrides_reach_the_solver():
    """surrogate.newton overrides newton key by key for FEM–ML runs (unset keys stay newton's)."""
    from granular_multiscale.drivers.fem_ml import fem_ml_config

    config = validate_config({"newton": {"line_search": True},
                              "surrogate": {"newton": {"acceleration": "anderson", "tangent_repair": "eig_floor"}}})
    newton = fem_ml_config(config)["newton"]
    assert (newton["acceleration"], newton["tangent_repair"]) == ("anderson", "eig_floor")
    assert newton["tolerance"] == 1e-4 and newton["line_search"] is True
    assert config["newton"]["acceleration"] == "none"  # the reference runs keep theirs
