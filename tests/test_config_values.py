"""Config values: every number finite (nan and ±inf refused, except +inf where the schema marks a
key x-allow-infinity), physical bounds, and output_dir. Pass criterion of every refusal: a
ConfigError whose message names the dotted key."""

import copy
import math
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from snakemake.utils import update_config

from granular_multiscale.config import ConfigError, load_config, validate_config

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = str(Path(sys.executable).with_name("snakemake"))


def nested(key: str, value) -> dict:
    """{'a': {'b': value}} from 'a.b'; a load path's strain is set in the default path2."""
    if key == "load_paths.path2.segments[1][1]":
        return {"load_paths": {"path2": {"segments": [[9, 0.009], [6, value], [42, 0.045]]}}}
    head, _, rest = key.partition(".")
    return {head: nested(rest, value) if rest else value}


def refused(config: dict, key: str) -> str:
    with pytest.raises(ConfigError) as error:
        validate_config(config)
    assert f"'{key}'" in str(error.value), str(error.value)
    return str(error.value)


KEYS = ["specimen.confining_pressure", "dem.strain_rate", "dem.friction", "load_paths.path2.segments[1][1]"]


# -- finite numbers ----------------------------------------------------------------------
@pytest.mark.parametrize("key", KEYS)
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_numbers_are_refused_naming_the_key(key, value):
    message = refused(nested(key, value), key)
    assert "is not a finite number" in message


@pytest.mark.parametrize("key", KEYS)
@pytest.mark.parametrize("text", ["nan", ".nan", ".NaN", "inf", ".inf", "-.inf", "1e999"])
def test_non_finite_strings_are_refused_naming_the_key(key, text):
    """As Snakemake's --config gives a value nested in a mapping: a string."""
    refused(nested(key, text), key)


@pytest.mark.parametrize("key", KEYS)
@pytest.mark.parametrize("text", [".nan", ".inf", "-.inf", "1e999", "1.0e+999"])
def test_non_finite_yaml_values_are_refused_naming_the_key(tmp_path, key, text):
    """1e999 is the case that made RVE preparation hang: YAML reads it as inf (or, as 1.1
    without a dot, as the string '1e999', which is read as a number)."""
    *parents, last = key.replace("segments[1][1]", "segments").split(".")
    value = f"[[9, 0.009], [6, {text}], [42, 0.045]]" if last == "segments" else text
    lines = [f"{'  ' * depth}{name}:" for depth, name in enumerate(parents)]
    lines.append(f"{'  ' * len(parents)}{last}: {value}")
    path = tmp_path / "values.yaml"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ConfigError) as error:
        load_config(path)
    assert f"'{key}'" in str(error.value)


def test_every_non_finite_number_is_named_at_once():
    message = refused({"specimen": {"confining_pressure": math.nan}, "dem": {"friction": math.inf}},
                      "specimen.confining_pressure")
    assert "'dem.friction'" in message


@pytest.mark.parametrize("value", [math.inf, ".inf", "inf", "1e999"])
def test_inf_still_means_never_promote_for_adaptive_thresholds(value):
    config = validate_config({"adaptive": {"thresholds": [value, 0.01], "correction_length": value}})
    assert config["adaptive"]["thresholds"] == [math.inf, 0.01]
    assert config["adaptive"]["correction_length"] == math.inf


@pytest.mark.parametrize("value", [math.nan, ".nan", -math.inf, "-.inf"])
def test_adaptive_thresholds_take_plus_inf_only(value):
    assert "a finite number, or .inf" in refused({"adaptive": {"thresholds": [0.02, value]}}, "adaptive.thresholds[1]")
    refused({"adaptive": {"correction_length": value}}, "adaptive.correction_length")


def test_a_problems_adaptive_run_takes_its_own_settings_over_the_section_adaptive():
    """Each problem's adaptive threshold: its own key (biaxial.adaptive.threshold: .inf by default);
    the key it replaced is refused, saying where its setting lives now."""
    config = validate_config({"footing": {"adaptive": {"indicator": "distance", "threshold": "inf"}}})
    assert config["footing"]["adaptive"] == {"indicator": "distance", "threshold": math.inf}
    assert config["biaxial"]["adaptive"] == {"threshold": math.inf} and config["adaptive"]["indicator"] == "spread"
    refused({"footing": {"adaptive": {"threshold": math.nan}}}, "footing.adaptive.threshold")
    refused({"biaxial": {"adaptive": {"indicator": "spreads"}}}, "biaxial.adaptive.indicator")
    assert "biaxial.adaptive.threshold" in refused({"adaptive": {"problem_threshold": 0.02}}, "adaptive.problem_threshold")


def test_a_nan_in_a_set_settings_is_named():
    sets = {"s": {"triaxial": 2, "settings": {"max_strain": math.nan}}}
    refused({"rve_paths": {"sets": sets}}, "rve_paths.sets.s.settings.max_strain")


# -- physical bounds ---------------------------------------------------------------------
@pytest.mark.parametrize(
    "key, value",
    [
        ("specimen.confining_pressure", 0.0),
        ("specimen.confining_pressure", 2.0e9),
        ("dem.friction", -0.1),
        ("dem.friction", 11.0),
        ("dem.poisson_ratio", 0.5),
        ("dem.density", 0.0),
        ("dem.strain_rate", 0.0),
        ("dem.strain_rate", 1.0e10),
        ("dem.damping", 1.0),
        ("dem.consolidation.unbalanced_tolerance", 1.0),
        ("newton.tolerance", 1.0),
        ("elastoplastic.friction", 20.0),
        ("linear_elastic.youngs_modulus", 1.0e13),
        ("surrogate.epochs", 0),
        ("load_paths.path2.segments[1][1]", 1.0),
        ("load_paths.path2.segments[1][1]", -1.5),
    ],
)
def test_values_outside_physical_bounds_name_the_key(key, value):
    refused(nested(key, value), key)


def test_the_smallest_sphere_must_be_smaller_than_the_largest():
    refused(nested("dem.diameter_min", 0.009), "dem.diameter_min")


@pytest.mark.parametrize("config, key, says", [
    ({"surrogate": {"weak_zone_sources": ["rve_paths:band"]}}, "surrogate.weak_zone_sources",
     "drives the specimen's packings"),
    ({"surrogate": {"weak_zone_sources": ["rve_paths:nowhere"]}}, "surrogate.weak_zone_sources", "names no set"),
    ({"surrogate": {"training_sources": ["path1", "rve_paths:band_weak"]}}, "surrogate.training_sources",
     "another material than the specimen's"),
])
def test_the_weak_zones_networks_train_on_the_weak_packing_and_only_they(config, key, says):
    assert says in refused(config, key)


def test_a_load_path_strain_out_of_bounds_from_a_string():
    refused(nested("load_paths.path2.segments[1][1]", "2.5"), "load_paths.path2.segments[1][1]")


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "config").glob("*.yaml")))
def test_every_config_file_is_within_the_bounds(name):
    """Alone and merged over config/config.yaml, as Snakemake loads it."""
    overlay = yaml.safe_load((ROOT / "config" / name).read_text())
    merged = copy.deepcopy(yaml.safe_load((ROOT / "config" / "config.yaml").read_text()))
    update_config(merged, overlay)
    validate_config(overlay)
    validate_config(merged)


# -- output_dir --------------------------------------------------------------------------
@pytest.mark.parametrize("value", ["", "   ", "/", "//", str(ROOT), str(ROOT) + "/", "."])
def test_output_dir_that_is_no_folder_of_its_own_is_refused(monkeypatch, value):
    monkeypatch.chdir(ROOT)  # "." is the repository when Snakemake runs in it
    refused({"output_dir": value}, "output_dir")


@pytest.mark.parametrize("value, normalised",
                         [("results/", "results"), ("results/tiny//", "results/tiny"), ("/tmp/x/", "/tmp/x"),
                          ("results", "results")])
def test_output_dir_is_normalised_and_stays_relative(value, normalised):
    assert validate_config({"output_dir": value})["output_dir"] == normalised


# -- the workflow refuses them before building the DAG ---------------------------------------
@pytest.mark.parametrize("how", ["config", "configfile"])
def test_snakemake_refuses_a_nan_with_one_line(tmp_path, how):
    """Pass criterion: exit status non-zero, one 'Configuration error: ...' line naming the key,
    no traceback, nothing written."""
    out = tmp_path / "out"
    if how == "config":  # Snakemake gives the nested value as the string '.nan'
        extra = ["--config", "specimen={confining_pressure: .nan}", f"output_dir={out}"]
    else:
        overlay = tmp_path / "nan.yaml"
        overlay.write_text(f"output_dir: {out}\nspecimen:\n  confining_pressure: .nan\n")
        extra = ["--configfile", "config/tiny.yaml", str(overlay)]
    result = subprocess.run([SNAKEMAKE, "-n", *extra], cwd=ROOT, capture_output=True, text=True, timeout=300)
    output = result.stdout + result.stderr
    assert result.returncode != 0
    errors = [line for line in output.splitlines() if line.startswith("Configuration error:")]
    assert len(errors) == 1 and "'specimen.confining_pressure'" in errors[0], output
    assert "Traceback" not in output
    assert not out.exists()
