"""Every figure and table of the report, rendered from real tiny runs of the project's FEM
solver (stand-ins for the surrogate stage: see analysis_fixtures.write_analysis_inputs).

Each figure must show the data of its files: the numbers its function drew are checked against
those computed here from the run files, dataset and tables (figure_checks); its PNG must exist
and have the size the settings ask for."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image

import figure_checks as check
from analysis_fixtures import write_analysis_inputs
from granular_multiscale import data
from granular_multiscale.analysis import figures, products, selection
from granular_multiscale.config import load_config
from granular_multiscale.plan import Plan

DPI = 50
SETTINGS = {"dpi": DPI, "figure_width": 10.0, "field_steps": [4, 16, -1], "deformation_scale": 1.0,
            "panel_pixels": [200, 300], "stress_strain_points": ["corner", "centre", "surface"],
            "stress_strain_gauss_points": []}
REF = "FEM, elastoplastic model (reference)"
ML = "FEM–ML (nn tangent)"
NOHIST = "FEM–ML, no history"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("analysis")
    config = load_config("config/tiny.yaml", {"reference_material": "elastoplastic", "output_dir": str(out)})
    info = write_analysis_inputs(out, config)
    plan = Plan(config)
    L = plan.layout
    files = {REF: plan.reference_run("path2"), ML: L.fem_ml("path2"), NOHIST: L.run("fem_ml_nohist", "path2")}
    return {"out": out, "layout": plan.layout, "plan": plan, "files": files, "config": config,
            "split": (plan.layout.dataset("train"), plan.layout.dataset("heldout")),
            "datasets": {label: data.read_run(path) for label, path in files.items()}, **info}


def check_png(path, kind, rows=1):
    check.check_png(path, products._size(SETTINGS, kind, rows=rows), DPI)


def test_error_map(runs):
    """Every point at its position, in its split's group, coloured by its own |σ_ML − σ_ref|."""
    out = runs["layout"].figure("error_map.png")
    drawn = products.make_error_map(runs["files"][REF], runs["files"][ML], *runs["split"], out, SETTINGS,
                                    path_label="Path2", reference_label=REF, surrogate_label=ML)
    check_png(out, "error_map")
    check.check_error_map(drawn, runs["datasets"][REF], runs["datasets"][ML], runs["train_gp"], runs["heldout_gp"])


def test_stress_strain_at_rule_chosen_held_out_points(runs):
    outs = {name: runs["layout"].figure(f"stress_strain_{name}.png") for name in selection.ANCHORS}
    chosen, drawn = products.make_stress_strain(runs["files"], *runs["split"], outs, SETTINGS, path_label="Path2")
    assert set(chosen.values()) <= set(runs["heldout_gp"].tolist())
    gp_z = runs["reference"]["gp_position"].sel(xyz="z").values
    assert gp_z[chosen["corner"]] == pytest.approx(max(gp_z[runs["heldout_gp"]]))
    assert list(drawn) == list(outs)
    for name, gp in chosen.items():
        check_png(outs[name], "line")
        check.check_stress_strain(drawn[name], runs["datasets"], gp)


def test_explicit_stress_strain_points_must_exist(runs):
    settings = {**SETTINGS, "stress_strain_gauss_points": [99]}
    with pytest.raises(ValueError, match="analysis.stress_strain_gauss_points"):
        products.stress_strain_points(runs["reference"], runs["heldout_gp"], settings)


def test_global_response(runs):
    out = runs["layout"].figure("top_force_volumetric_strain.png")
    drawn = products.make_global_response(runs["files"], out, SETTINGS, path_label="Path2")
    check_png(out, "line")
    check.check_global_response(drawn, runs["datasets"])


@pytest.mark.parametrize("quantity", ["axial_displacement", "shear_strain", "sigma23"])
def test_field_figures(runs, quantity):
    out = runs["layout"].figure(f"fields_{quantity}.png")
    drawn = products.make_field_figure(runs["files"][REF], runs["files"][ML], quantity, out, SETTINGS,
                                       path_label="Path2", reference_label=REF, surrogate_label=ML)
    check_png(out, "field_row", rows=3)
    steps = [4, 16, 57]  # field_steps 4, 16, -1 of the 57 load steps
    check.check_fields(drawn, runs["datasets"][REF], runs["datasets"][ML], quantity, steps)
    # what the data cannot show: the off-screen renderer drew the meshes (coloured pixels in the left column)
    image = np.asarray(Image.open(out).convert("RGB"), dtype=float)
    left = image[:, : image.shape[1] // 3]
    saturation = left.max(axis=2) - left.min(axis=2)
    assert np.mean(saturation > 60) > 0.02, f"{out}: no coloured mesh in the reference column"


def test_training_curves(runs):
    curves = runs["plan"].training_curves()
    out = runs["layout"].figure("training_curves.png")
    drawn = products.make_training_curves(curves, out, SETTINGS)
    check_png(out, "line")
    check.check_training_curves(drawn, curves)
    assert list(drawn) == ["NNσ", "ND"]


def test_tables_speed_vs_error_and_headline(runs):
    L = runs["layout"]
    speed = products.make_speedup_outputs(runs["files"], L.table("speedup.csv"), L.table("speedup.html"),
                                          path_label="Path2", paper_reference=runs["config"]["analysis"]["paper_reference"],
                                          machine="test machine")
    assert speed["method"].tolist() == [REF, ML, NOHIST, "FEM–DEM", "FEM–ML"]
    assert speed["load_steps"].tolist()[:3] == [57, 57, 57]
    assert speed["speedup"].iloc[0] == 1.0 and speed["speedup"].iloc[-1] == 125
    accuracy = products.make_accuracy_table(runs["files"], *runs["split"], L.table("accuracy.csv"),
                                            L.table("accuracy.html"), path_label="Path2")
    # the close imitation is far closer to the reference than linear elasticity
    by = accuracy.set_index("method")
    assert by.loc[ML, "stress_mae_heldout_kpa"] < 0.5 * by.loc[NOHIST, "stress_mae_heldout_kpa"]
    assert by.loc[ML, "top_force_max_rel_pct"] < by.loc[NOHIST, "top_force_max_rel_pct"]
    assert pd.read_csv(L.table("accuracy.csv")).shape == (2, 10)
    fig = L.figure("speed_vs_error.png")
    drawn = products.make_speed_vs_error(L.table("speedup.csv"), L.table("accuracy.csv"), fig, SETTINGS)
    check_png(fig, "speed")
    check.check_speed_vs_error(drawn, L.table("speedup.csv"), L.table("accuracy.csv"))
    headline = products.make_headline(L.table("speedup.csv"), L.table("accuracy.csv"),
                                      L.table("headline.json"), config=runs["config"], reference_label=REF,
                                      surrogate_label=ML, ablation_label=NOHIST)
    saved = json.loads(Path(L.table("headline.json")).read_text())
    assert saved["speedup"] == pytest.approx(speed.set_index("method").loc[ML, "speedup"])
    assert saved["stress_mae_heldout_kpa"] == pytest.approx(by.loc[ML, "stress_mae_heldout_kpa"])
    assert saved["gauss_points"] == 16 and saved["machine"]["cores"] >= 1
    assert headline["ablation_top_force_max_rel_pct"] > headline["top_force_max_rel_pct"]


def test_a_run_that_stopped_early_is_reported_over_the_steps_it_reached(runs, tmp_path):
    """A FEM–ML run kept after Newton failed at step 21 (attribute completed = 0, 20 load steps):
    every table and figure accepts it, compares it over steps 0..20 and says it stopped."""
    full = data.read_run(runs["files"][ML])
    partial = full.isel(step=slice(0, 21)).copy(deep=True)
    partial.attrs["completed"] = 0
    partial_file = tmp_path / "fem_ml_partial.h5"
    partial.to_netcdf(partial_file, engine=data.ENGINE)
    files = {REF: runs["files"][REF], ML: str(partial_file)}
    split = runs["split"]

    accuracy = products.make_accuracy_table(files, *split, tmp_path / "accuracy.csv", tmp_path / "accuracy.html",
                                            path_label="Path2").set_index("method")
    complete = products.make_accuracy_table(runs["files"], *split, tmp_path / "a_full.csv", tmp_path / "a_full.html",
                                            path_label="Path2").set_index("method")
    assert accuracy.loc[ML, "load_steps_compared"] == 20 and complete.loc[ML, "load_steps_compared"] == 57
    # the same stresses over fewer steps: the error differs from the whole path's, and is finite
    assert np.isfinite(accuracy.loc[ML, "stress_mae_all_kpa"])
    assert accuracy.loc[ML, "stress_mae_all_kpa"] != pytest.approx(complete.loc[ML, "stress_mae_all_kpa"])

    speed = products.make_speedup_outputs(files, tmp_path / "speedup.csv", tmp_path / "speedup.html",
                                          path_label="Path2", paper_reference=None, machine="test").set_index("method")
    assert speed.loc[ML, "completed"] == "no" and speed.loc[ML, "load_steps"] == 20
    per_step = lambda label, steps: speed.loc[label, "wall_time_s"] / steps  # noqa: E731
    assert speed.loc[ML, "speedup"] == pytest.approx(per_step(REF, 57) / per_step(ML, 20))

    fig = tmp_path / "speed_vs_error.png"
    drawn = products.make_speed_vs_error(tmp_path / "speedup.csv", tmp_path / "accuracy.csv", fig, SETTINGS)
    check_png(fig, "speed")
    check.check_speed_vs_error(drawn, tmp_path / "speedup.csv", tmp_path / "accuracy.csv")
    assert f"{ML} (stopped after step 20; time and error of those steps)" in drawn["top_force_max_rel_pct"]
    assert products.legend_label(ML, partial) == f"{ML} (stopped after step 20)"
    field = tmp_path / "fields.png"  # steps 4, 16 reached; the last (57) not
    drawn = products.make_field_figure(files[REF], files[ML], "sigma23", field, SETTINGS, path_label="Path2",
                                       reference_label=REF, surrogate_label=ML)
    check_png(field, "field_row", rows=3)
    check.check_fields(drawn, runs["datasets"][REF], partial, "sigma23", [4, 16, 57])
    assert list(drawn[57]) == ["reference"]
    drawn = products.make_global_response(files, tmp_path / "global.png", SETTINGS, path_label="Path2")
    check_png(tmp_path / "global.png", "line")
    check.check_global_response(drawn, {REF: runs["datasets"][REF], f"{ML} (stopped after step 20)": partial})


def test_a_complete_run_with_fewer_steps_is_another_path(runs, tmp_path):
    short = data.read_run(runs["files"][ML]).isel(step=slice(0, 21))
    short.attrs["completed"] = 1
    short.to_netcdf(tmp_path / "short.h5", engine=data.ENGINE)
    with pytest.raises(ValueError, match=r"short\.h5.*21 steps, the reference has 58"):
        products.make_accuracy_table({REF: runs["files"][REF], ML: str(tmp_path / "short.h5")}, *runs["split"],
                                     tmp_path / "a.csv", tmp_path / "a.html", path_label="Path2")


def test_training_curves_draw_every_ensemble_member(monkeypatch, tmp_path):
    """An ensemble's loss table (column member) gives one curve pair per member, one legend entry pair."""
    epochs = np.arange(1, 11)
    table = pd.concat([pd.DataFrame({"epoch": epochs, "train_loss": (m + 1) / epochs, "heldout_loss": (m + 2) / epochs,
                                     "member": m}) for m in range(3)])
    saved = []
    monkeypatch.setattr(figures, "save_figure", lambda fig, out, dpi: saved.append(fig))  # keep it for its legend
    drawn = figures.training_curves({"NNσ|with history": table}, tmp_path / "x.png")
    series = "(with history, 3 members)"
    assert list(drawn) == ["NNσ"]
    assert list(drawn["NNσ"]) == [f"{line} {series}, member {m}" for m in range(3)
                                  for line in ("training", "held out")]
    for m in range(3):  # each member its own curves over the epochs, not chained end to end
        check.assert_curve(drawn["NNσ"][f"training {series}, member {m}"], epochs, (m + 1) / epochs, f"member {m}")
        check.assert_curve(drawn["NNσ"][f"held out {series}, member {m}"], epochs, (m + 2) / epochs, f"member {m}")
    assert [t.get_text() for t in saved[0].axes[0].get_legend().get_texts()] == [
        f"training {series}", f"held out {series}"]
