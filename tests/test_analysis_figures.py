"""Every figure and table of the report, rendered from real tiny runs of the project's FEM
solver (stand-ins for the surrogate stage: see analysis_fixtures.write_analysis_inputs).

Each PNG must exist, have the size the settings ask for, and not be blank."""

import json

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from analysis_fixtures import write_analysis_inputs
from granular_multiscale.analysis import figures, products, selection
from granular_multiscale.config import load_config

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
    files = {REF: out / "fem_elastoplastic/path2.h5", ML: out / "fem_ml/path2.h5", NOHIST: out / "fem_ml_nohist/path2.h5"}
    return {"out": out, "files": {k: str(v) for k, v in files.items()}, "config": config, **info}


def check_png(path, width_in, height_in):
    image = np.asarray(Image.open(path).convert("RGB"), dtype=float)
    assert image.shape[:2] == (round(height_in * DPI), round(width_in * DPI)), path
    assert image.std() > 10, f"{path} looks blank"
    not_white = np.mean(image.min(axis=2) < 240)
    assert not_white > 0.03, f"{path}: only {not_white:.1%} of the pixels are drawn"
    return image


def test_error_map(runs):
    out = runs["out"] / "figures/error_map.png"
    products.make_error_map(runs["files"][REF], runs["files"][ML], runs["out"] / "dataset/train.h5",
                            runs["out"] / "dataset/heldout.h5", out, SETTINGS, path_label="Path2",
                            reference_label=REF, surrogate_label=ML)
    check_png(out, *products._size(SETTINGS, "error_map"))


def test_stress_strain_at_rule_chosen_held_out_points(runs):
    outs = {name: runs["out"] / f"figures/stress_strain_{name}.png" for name in selection.ANCHORS}
    chosen = products.make_stress_strain(runs["files"], runs["out"] / "dataset/train.h5",
                                         runs["out"] / "dataset/heldout.h5", outs, SETTINGS, path_label="Path2")
    assert set(chosen.values()) <= set(runs["heldout_gp"].tolist())
    gp_z = runs["reference"]["gp_position"].sel(xyz="z").values
    assert gp_z[chosen["corner"]] == pytest.approx(max(gp_z[runs["heldout_gp"]]))
    for path in outs.values():
        check_png(path, *products._size(SETTINGS, "line"))


def test_explicit_stress_strain_points_must_exist(runs):
    settings = {**SETTINGS, "stress_strain_gauss_points": [99]}
    with pytest.raises(ValueError, match="analysis.stress_strain_gauss_points"):
        products.stress_strain_points(runs["reference"], runs["heldout_gp"], settings)


def test_global_response(runs):
    out = runs["out"] / "figures/top_force_volumetric_strain.png"
    products.make_global_response(runs["files"], out, SETTINGS, path_label="Path2")
    check_png(out, *products._size(SETTINGS, "line"))


@pytest.mark.parametrize("quantity", ["axial_displacement", "shear_strain", "sigma23"])
def test_field_figures(runs, quantity):
    out = runs["out"] / f"figures/fields_{quantity}.png"
    products.make_field_figure(runs["files"][REF], runs["files"][ML], quantity, out, SETTINGS,
                               path_label="Path2", reference_label=REF, surrogate_label=ML)
    image = check_png(out, *products._size(SETTINGS, "field_row", rows=3))
    # the rendered specimens: the left column must hold coloured (not grey/white) pixels
    left = image[:, : image.shape[1] // 3]
    saturation = left.max(axis=2) - left.min(axis=2)
    assert np.mean(saturation > 60) > 0.02, f"{out}: no coloured mesh in the reference column"


def test_training_curves(runs):
    curves = {f"{net}|{series}": runs["out"] / f"training/{name}.csv"
              for net, series, name in (("NNσ", "with history", "sigma"), ("ND", "with history", "tangent"),
                                        ("NNσ", "no history", "sigma_nohist"), ("ND", "no history", "tangent_nohist"))}
    out = runs["out"] / "figures/training_curves.png"
    products.make_training_curves(curves, out, SETTINGS)
    check_png(out, *products._size(SETTINGS, "line"))


def test_tables_speed_vs_error_and_headline(runs):
    out = runs["out"]
    speed = products.make_speedup_outputs(runs["files"], out / "tables/speedup.csv", out / "tables/speedup.html",
                                          path_label="Path2", paper_reference=runs["config"]["analysis"]["paper_reference"],
                                          machine="test machine")
    assert speed["method"].tolist() == [REF, ML, NOHIST, "FEM–DEM", "FEM–ML"]
    assert speed["load_steps"].tolist()[:3] == [57, 57, 57]
    assert speed["speedup"].iloc[0] == 1.0 and speed["speedup"].iloc[-1] == 125
    accuracy = products.make_accuracy_table(runs["files"], out / "dataset/train.h5", out / "dataset/heldout.h5",
                                            out / "tables/accuracy.csv", out / "tables/accuracy.html", path_label="Path2")
    # the close imitation is far closer to the reference than linear elasticity
    by = accuracy.set_index("method")
    assert by.loc[ML, "stress_mae_heldout_kpa"] < 0.5 * by.loc[NOHIST, "stress_mae_heldout_kpa"]
    assert by.loc[ML, "top_force_max_rel_pct"] < by.loc[NOHIST, "top_force_max_rel_pct"]
    assert pd.read_csv(out / "tables/accuracy.csv").shape == (2, 10)
    fig = out / "figures/speed_vs_error.png"
    products.make_speed_vs_error(out / "tables/speedup.csv", out / "tables/accuracy.csv", fig, SETTINGS)
    check_png(fig, *products._size(SETTINGS, "speed"))
    headline = products.make_headline(out / "tables/speedup.csv", out / "tables/accuracy.csv",
                                      out / "tables/headline.json", config=runs["config"], reference_label=REF,
                                      surrogate_label=ML, ablation_label=NOHIST)
    saved = json.loads((out / "tables/headline.json").read_text())
    assert saved["speedup"] == pytest.approx(speed.set_index("method").loc[ML, "speedup"])
    assert saved["stress_mae_heldout_kpa"] == pytest.approx(by.loc[ML, "stress_mae_heldout_kpa"])
    assert saved["gauss_points"] == 16 and saved["machine"]["cores"] >= 1
    assert headline["ablation_top_force_max_rel_pct"] > headline["top_force_max_rel_pct"]


def test_a_run_that_stopped_early_is_reported_over_the_steps_it_reached(runs, tmp_path):
    """A FEM–ML run kept after Newton failed at step 21 (attribute completed = 0, 20 load steps):
    every table and figure accepts it, compares it over steps 0..20 and says it stopped."""
    from granular_multiscale import data

    full = data.read_run(runs["files"][ML])
    partial = full.isel(step=slice(0, 21)).copy(deep=True)
    partial.attrs["completed"] = 0
    partial_file = tmp_path / "fem_ml_partial.h5"
    partial.to_netcdf(partial_file, engine=data.ENGINE)
    files = {REF: runs["files"][REF], ML: str(partial_file)}
    split = (runs["out"] / "dataset/train.h5", runs["out"] / "dataset/heldout.h5")

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
    products.make_speed_vs_error(tmp_path / "speedup.csv", tmp_path / "accuracy.csv", fig, SETTINGS)
    check_png(fig, *products._size(SETTINGS, "speed"))
    assert products.legend_label(ML, partial) == f"{ML} (stopped after step 20)"
    field = tmp_path / "fields.png"  # steps 4, 16 reached; the last (57) not
    products.make_field_figure(files[REF], files[ML], "sigma23", field, SETTINGS, path_label="Path2",
                               reference_label=REF, surrogate_label=ML)
    check_png(field, *products._size(SETTINGS, "field_row", rows=3))
    products.make_global_response(files, tmp_path / "global.png", SETTINGS, path_label="Path2")
    check_png(tmp_path / "global.png", *products._size(SETTINGS, "line"))


def test_a_complete_run_with_fewer_steps_is_another_path(runs, tmp_path):
    from granular_multiscale import data

    short = data.read_run(runs["files"][ML]).isel(step=slice(0, 21))
    short.attrs["completed"] = 1
    short.to_netcdf(tmp_path / "short.h5", engine=data.ENGINE)
    with pytest.raises(ValueError, match=r"short\.h5.*21 steps, the reference has 58"):
        products.make_accuracy_table({REF: runs["files"][REF], ML: str(tmp_path / "short.h5")},
                                     runs["out"] / "dataset/train.h5", runs["out"] / "dataset/heldout.h5",
                                     tmp_path / "a.csv", tmp_path / "a.html", path_label="Path2")


def test_training_curves_draw_every_ensemble_member(monkeypatch, tmp_path):
    """An ensemble's loss table (column member) gives one curve pair per member, one legend entry pair."""
    epochs = np.arange(1, 11)
    table = pd.concat([pd.DataFrame({"epoch": epochs, "train_loss": (m + 1) / epochs, "heldout_loss": (m + 2) / epochs,
                                     "member": m}) for m in range(3)])
    monkeypatch.setattr(figures, "save_figure", lambda fig, out, dpi: fig)  # keep the figure to inspect it
    fig = figures.training_curves({"NNσ|with history": table}, tmp_path / "x.png")
    ax = fig.axes[0]
    assert len(ax.lines) == 6
    np.testing.assert_array_equal(ax.lines[4].get_xdata(), epochs)  # members are not chained end to end
    assert [t.get_text() for t in ax.get_legend().get_texts()] == [
        "training (with history, 3 members)", "held out (with history, 3 members)"]
