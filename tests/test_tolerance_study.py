"""The reference's own convergence error: the tolerance-study table against direct
recomputation, its error falling with the tolerance, and the rule at the tiny scale with YADE."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from test_fem_newton import ElasticTangentElastoplastic

from granular_multiscale.analysis.convergence import tolerance_table
from granular_multiscale.data import read_run
from granular_multiscale.fem.newton import NewtonSettings
from granular_multiscale.fem.triaxial import TriaxialProblem
from granular_multiscale.paths import LoadPath
from granular_multiscale.plan import Layout

ROOT = Path(__file__).resolve().parents[1]
PATH = LoadPath("p", ((6, 0.006), (3, 0.003), (8, 0.02)))


def _run(tolerance, predictor="extrapolate", acceleration="anderson"):
    problem = TriaxialProblem(elements=(1, 1, 2), platen="rough", newton=NewtonSettings(
        tolerance=tolerance, max_iterations=300, predictor=predictor, acceleration=acceleration))
    return problem.run(ElasticTangentElastoplastic(16, initial_stress=problem.initial_stress), PATH, progress=False)


def test_table_numbers_and_the_error_falling_with_the_tolerance():
    """Elastoplastic stresses with a too-stiff tangent (the DEM situation): the study's
    differences are those of the files, zero for the converged variant, and shrink with the
    tolerance; the cost ratio is the evaluations per step over the baseline's."""
    settings = {f"t{t:g}": {"tolerance": t, "predictor": "extrapolate", "acceleration": "anderson"}
                for t in (3e-2, 1e-2, 1e-3, 1e-6)}
    settings["plain"] = {"tolerance": 3e-2, "predictor": "tangent", "acceleration": "none"}
    runs = {name: _run(**s) for name, s in settings.items()}
    table = tolerance_table(runs, settings, converged="t1e-06", baseline="plain").set_index("variant")
    limit = runs["t1e-06"]
    for name, run in runs.items():
        row = table.loc[name]
        peak = np.abs(limit.top_force.values).max()
        assert row.top_force_max_pct == pytest.approx(100 * np.abs(run.top_force.values - limit.top_force.values).max()
                                                      / peak)
        v = limit.volumetric_strain.values
        assert row.volumetric_strain_max_pct == pytest.approx(100 * np.abs(run.volumetric_strain.values - v).max()
                                                              / np.abs(v).max())
        assert row.stress_mae_kpa == pytest.approx(1e-3 * np.abs(run.stress.values[1:] - limit.stress.values[1:]).mean())
        assert row.evaluations_per_step == pytest.approx(run.material_evaluations.values[1:].mean())
        assert row.residual_relative_max <= settings[name]["tolerance"]
        assert row.cost_ratio == pytest.approx(row.evaluations_per_step / table.loc["plain", "evaluations_per_step"])
    assert table.loc["t1e-06", ["top_force_max_pct", "volumetric_strain_max_pct", "stress_mae_kpa"]].max() == 0
    errors = table.loc[["t0.03", "t0.01", "t0.001"], "top_force_max_pct"].to_numpy()
    assert np.all(np.diff(errors) < 0) and errors[-1] < 0.2 * errors[0]
    # the solver matters as much as the tolerance: same tolerance, fewer evaluations
    assert table.loc["t0.03", "evaluations_per_step"] < table.loc["plain", "evaluations_per_step"]
    with pytest.raises(KeyError, match="tolerance_study.converged"):
        tolerance_table(runs, settings, converged="nope")


@pytest.mark.needs_yade
@pytest.mark.slow
def test_rule_at_the_tiny_scale(tmp_path):
    """`snakemake tolerance_study` with real YADE RVEs: one run per variant, the table, the
    figure, and the report of `all tolerance_study` shows them."""
    out = tmp_path / "out"
    config = {
        "output_dir": str(out),
        "load_paths": {"p": {"segments": [[4, 0.004], [2, 0.002], [4, 0.006]]}},
        "training_path": "p", "validation_path": "p",
        "surrogate": {"training_sources": ["p"]},  # config/tiny.yaml's name path1, not defined here
        "dem": {"n_spheres": 100},
        "tolerance_study": {
            "path": "p", "converged": "tight", "baseline": "plain",
            "variants": {
                "plain": {"tolerance": 2.0e-2, "max_iterations": 8, "predictor": "tangent", "acceleration": "none"},
                "loose": {"tolerance": 2.0e-2, "max_iterations": 8},
                "tight": {"tolerance": 1.0e-3},
            },
        },
    }
    config_file = tmp_path / "config.yaml"
    config_file.write_text(yaml.safe_dump(config))
    snakemake = [sys.executable, "-m", "snakemake", "--configfile", "config/tiny.yaml", str(config_file)]
    result = subprocess.run([*snakemake, "-j2", "--", "tolerance_study"], cwd=ROOT, capture_output=True, text=True,
                            timeout=1200)
    assert result.returncode == 0, result.stderr[-4000:]
    L = Layout(out)
    table = pd.read_csv(L.table("tolerance_study.csv")).set_index("variant")
    assert set(table.index) == {"plain", "loose", "tight"}
    for name, tolerance in (("plain", 2e-2), ("loose", 2e-2), ("tight", 1e-3)):
        run = read_run(L.tolerance_run(name, "p"))
        assert run.attrs["newton_tolerance"] == tolerance and run.sizes["step"] == 11
        assert (run.residual_relative.values <= tolerance).all()
        assert table.loc[name, "particle_steps_per_step"] == pytest.approx(run.particle_steps.values[1:].mean())
        assert Path(L.log(f"tolerance_study/{name}/p")).is_file()
        assert Path(L.benchmark(f"tolerance_study/{name}/p")).is_file()
    assert table.loc["tight", "top_force_max_pct"] == 0 and table.loc["loose", "top_force_max_pct"] > 0
    assert Path(L.figure("tolerance_study.png")).stat().st_size > 10_000
    html = Path(L.table("tolerance_study.html")).read_text()
    assert "converged variant tight" in html


def test_config_errors_name_the_key():
    from granular_multiscale.config import ConfigError, load_config

    with pytest.raises(ConfigError, match=r"tolerance_study.converged': 'nope' is not one of the variants"):
        load_config(overrides={"tolerance_study.converged": "nope"})
    with pytest.raises(ConfigError, match=r"tolerance_study.path': unknown path 'path9'"):
        load_config(overrides={"tolerance_study.path": "path9"})
    with pytest.raises(ConfigError, match=r"tolerance_study.variants.bad.predictor"):
        load_config(overrides={"tolerance_study.variants": {"a": {"tolerance": 1e-3},
                                                            "bad": {"tolerance": 1e-3, "predictor": "linear"}},
                               "tolerance_study.converged": "a", "tolerance_study.baseline": "a"})
    assert load_config()["tolerance_study"]["path"] == "path2"  # the validation path by default


def test_self_consistency_finds_the_reference_settings_in_the_study(tmp_path):
    from granular_multiscale.analysis.convergence import newton_settings_of, self_consistency

    runs = {"a": _run(1e-2), "b": _run(1e-3), "c": _run(1e-6), "d": _run(1e-3, "tangent", "none")}
    settings = {k: {"tolerance": float(r.attrs["newton_tolerance"]), "predictor": r.attrs["newton_predictor"],
                    "acceleration": r.attrs["newton_acceleration"]} for k, r in runs.items()}
    table = tolerance_table(runs, settings, converged="c", baseline="a")
    table.to_csv(tmp_path / "study.csv", index=False)
    newton = newton_settings_of(runs["b"])
    assert newton == {"tolerance": 1e-3, "predictor": "extrapolate", "acceleration": "anderson",
                      "residual_relative_max": pytest.approx(runs["b"].residual_relative.values.max())}
    found = self_consistency(tmp_path / "study.csv", newton)
    row = table.set_index("variant").loc["b"]
    assert found["variant"] == "b" and found["converged_tolerance"] == 1e-6
    assert found["top_force_max_pct"] == pytest.approx(row.top_force_max_pct) and row.top_force_max_pct > 0
    # the same tolerance with another solver is another row; an unstudied setting has none
    assert self_consistency(tmp_path / "study.csv", newton_settings_of(runs["d"]))["variant"] == "d"
    assert self_consistency(tmp_path / "study.csv", dict(newton, tolerance=5e-3)) is None
    assert self_consistency(tmp_path / "missing.csv", newton) is None


def test_newton_settings_of_an_older_file_come_from_its_stored_config(tmp_path):
    """Files written before the newton_predictor/newton_acceleration attributes: the config
    stored with the run says it (a FEM–DEM run's dem.newton overriding newton)."""
    from granular_multiscale.analysis.convergence import newton_settings_of
    from granular_multiscale.config import load_config
    from granular_multiscale.data import write_run

    run = _run(2e-3)
    del run.attrs["newton_predictor"], run.attrs["newton_acceleration"]
    run.attrs["method"] = "dem"
    write_run(run, tmp_path / "old.h5", load_config())
    settings = newton_settings_of(read_run(tmp_path / "old.h5"))
    assert (settings["predictor"], settings["acceleration"]) == ("extrapolate", "anderson")  # dem.newton's
    run.attrs["method"] = "elastoplastic"
    write_run(run, tmp_path / "other.h5", load_config())
    assert newton_settings_of(read_run(tmp_path / "other.h5"))["predictor"] == "tangent"  # newton's
