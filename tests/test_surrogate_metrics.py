"""Accuracy metrics against a reference run: known perturbations give known numbers."""

import numpy as np
import pytest
import xarray as xr

from granular_multiscale.analysis import metrics
from granular_multiscale.tensors import COMP


def reference_run(n_steps=7, n_gp=4):
    rng = np.random.default_rng(0)
    stress = -1e5 + rng.normal(scale=2e4, size=(n_steps, n_gp, 6))
    stress[..., 3:] = rng.normal(scale=1e3, size=(n_steps, n_gp, 3))
    phase = np.array(["initial", "loading", "loading", "unloading", "unloading", "reloading", "reloading"][:n_steps])
    return xr.Dataset(
        {
            "stress": (("step", "gp", "comp"), stress),
            "gp_position": (("gp", "xyz"), rng.uniform(size=(n_gp, 3))),
            "axial_strain": ("step", np.linspace(0, 0.01, n_steps)),
            "top_force": ("step", np.array([-25e3, -50e3, -60e3, -20e3, 500.0, -40e3, -70e3][:n_steps]), {"units": "N"}),
            "volumetric_strain": ("step", np.linspace(0, -0.002, n_steps)),
            "phase": ("step", phase),
            "newton_iterations": ("step", np.array([0, 3, 2, 2, 2, 3, 2][:n_steps])),
            "cutbacks": ("step", np.zeros(n_steps, int)),
        },
        coords={"step": np.arange(n_steps), "gp": np.arange(n_gp), "comp": list(COMP)},
    )


def test_stress_errors_by_point_and_split():
    ref = reference_run()
    run = ref.copy(deep=True)
    run["stress"][:, 1, 2] += 3000.0  # gp 1: σ33 off by 3 kPa at every step
    run["stress"][:, 3, 0] -= 1000.0  # gp 3: σ11 off by 1 kPa
    by_gp = metrics.stress_error_by_gp(ref, run, train_gp=[0, 1], heldout_gp=[2, 3])
    assert list(by_gp.split) == ["train", "train", "heldout", "heldout"]
    assert by_gp.loc[1, "mae_33_pa"] == pytest.approx(3000.0)
    assert by_gp.loc[1, "mae_mean_pa"] == pytest.approx(500.0)
    assert by_gp.loc[0, "mae_mean_pa"] == 0.0
    expected_rel = 3000.0 / metrics.stress_norm(ref.stress.values[:, 1])
    assert by_gp.loc[1, "relative_error_mean"] == pytest.approx(expected_rel.mean())
    assert by_gp.loc[1, "relative_error_max"] == pytest.approx(expected_rel.max())
    summary = metrics.stress_error_summary(ref, run, train_gp=[0, 1], heldout_gp=[2, 3]).set_index("split")
    assert summary.loc["train", "mae_33_pa"] == pytest.approx(1500.0)  # one of two points off by 3 kPa
    assert summary.loc["heldout", "mae_11_pa"] == pytest.approx(500.0)
    assert summary.loc["all", "mae_33_pa"] == pytest.approx(750.0)
    assert summary.loc["heldout", "n_gp"] == 2


def test_curve_errors_per_phase():
    ref = reference_run()
    run = ref.copy(deep=True)
    run["top_force"] = ref.top_force * 1.02  # 2 % everywhere
    run["top_force"][4] = 1500.0  # a step where the reference force nearly vanishes (500 N)
    table = metrics.curve_errors(ref, run).set_index(["quantity", "phase"])
    force = table.loc[("top_force", "all")]
    # the near-zero step (500 N < 1 % of the 70 kN peak) is left out of the pointwise ratio
    assert force["max_relative_error_percent"] == pytest.approx(2.0)
    assert force["steps_below_1pct_of_peak"] == 1
    assert force["max_abs_error"] == pytest.approx(1400.0)  # 2 % of the 70 kN peak
    assert force["max_error_percent_of_peak"] == pytest.approx(2.0)
    assert table.loc[("top_force", "unloading"), "max_abs_error"] == pytest.approx(1000.0)
    assert table.loc[("top_force", "loading"), "max_abs_error"] == pytest.approx(1200.0)
    assert set(table.loc["volumetric_strain"].index) == {"all", "loading", "unloading", "reloading"}
    assert table.loc[("volumetric_strain", "all"), "max_abs_error"] == 0.0


def test_newton_and_out_of_range_tables():
    ref = reference_run()
    run = ref.copy(deep=True)
    run["newton_iterations"] = ref.newton_iterations * 2
    run["out_of_range_points"] = ("step", np.array([0, 0, 1, 3, 0, 0, 0.0]))
    run["out_of_range_excess"] = ("step", np.array([0, 0, 0.1, 0.4, 0, 0, 0.0]))
    table = metrics.newton_iterations({"reference": ref, "nn": run})
    assert list(table.iterations_nn) == [0, 6, 4, 4, 4, 6, 4]
    assert list(table.phase)[3] == "unloading"
    oor = metrics.out_of_range({"reference": ref, "nn": run})
    assert list(oor.run) == ["nn"]
    assert oor.loc[0, "steps_with_out_of_range_inputs"] == 2 and oor.loc[0, "max_points_out_of_range"] == 3
    assert oor.loc[0, "max_excess_of_training_range"] == pytest.approx(0.4)


def test_runs_that_do_not_match_are_refused():
    ref = reference_run()
    with pytest.raises(ValueError, match="steps"):
        metrics.curve_errors(ref, ref.isel(step=slice(0, 5)))
    other = ref.copy(deep=True)
    other["axial_strain"] = ref.axial_strain * 2
    with pytest.raises(ValueError, match="another load path"):
        metrics.stress_error_by_gp(ref, other, [0], [1])
    moved = ref.copy(deep=True)
    moved["gp_position"] = ref.gp_position + 0.1
    with pytest.raises(ValueError, match="another mesh"):
        metrics.compare(ref, moved, [0], [1], run="x")
    tables = metrics.compare(ref, ref, [0, 1], [2, 3], path="path2", run="fem_ml")
    assert list(tables["curve_errors"].columns[:2]) == ["path", "run"]


def test_newton_table_keeps_a_run_that_stopped_early():
    ref = reference_run()
    stopped = ref.isel(step=slice(0, 4))
    table = metrics.newton_iterations({"reference": ref, "nn": stopped})
    assert list(table.iterations_nn.iloc[:4]) == [0, 3, 2, 2]
    assert table.iterations_nn.iloc[4:].isna().all()
    with pytest.raises(ValueError, match="schedule"):
        metrics.newton_iterations({"reference": ref, "x": ref.assign(axial_strain=ref.axial_strain * 2)})


def test_partial_run_is_compared_over_the_steps_it_reached():
    ref = reference_run()
    partial = ref.isel(step=slice(0, 4)).copy(deep=True)
    partial.attrs["completed"] = 0
    partial["top_force"] = partial.top_force * 1.01
    tables = metrics.compare(ref, partial, [0, 1], [2, 3], run="fem_ml")
    curves = tables["curve_errors"].set_index(["quantity", "phase"])
    assert curves.loc[("top_force", "all"), "completed"] == 0
    assert curves.loc[("top_force", "all"), "steps_compared"] == 4
    assert curves.loc[("top_force", "all"), "max_relative_error_percent"] == pytest.approx(1.0)
    assert "reloading" not in curves.loc["top_force"].index  # not reached
    # a complete run that is short is still refused
    with pytest.raises(ValueError, match="steps"):
        metrics.compare(ref, ref.isel(step=slice(0, 4)), [0], [1])
