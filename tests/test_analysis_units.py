"""Analysis building blocks against hand-computed values: invariants, the Gauss-point rule,
the VTK hex grid, tables and the VTU export."""

import numpy as np
import pandas as pd
import pytest
import pyvista as pv
from skfem import MeshHex

from analysis_fixtures import PATH2, make_run, mesh_and_gauss_points
from granular_multiscale.analysis import fields, quantities, selection, tables


# -- invariants ------------------------------------------------------------------------


def test_triaxial_compression_invariants():
    # σ_radial = −100 kPa, σ_axial = −300 kPa: q = 200 kPa, p = 166.67 kPa
    stress = np.array([-100e3, -100e3, -300e3, 0.0, 0.0, 0.0])
    assert quantities.deviatoric_stress(stress) == pytest.approx(200e3)
    assert quantities.mean_stress(stress) == pytest.approx(500e3 / 3)
    # triaxial extension (axial less compressive than radial): q negative, same magnitude
    extension = np.array([-300e3, -300e3, -100e3, 0.0, 0.0, 0.0])
    assert quantities.deviatoric_stress(extension) == pytest.approx(-200e3)


def test_deviatoric_stress_of_pure_shear():
    # σ23 = τ only: J2 = τ², q = √3 τ (sign: axial not more compressive -> +)
    tau = 7e3
    assert abs(quantities.deviatoric_stress(np.array([0, 0, 0, tau, 0, 0.0]))) == pytest.approx(np.sqrt(3) * tau)


def test_equivalent_shear_strain():
    e = 0.01
    # isochoric uniaxial compression: ε_s equals the axial strain
    assert quantities.equivalent_shear_strain(np.array([e / 2, e / 2, -e, 0, 0, 0])) == pytest.approx(e)
    # simple shear with tensorial ε12 = g (γ = 2g): ε_s = γ/√3
    g = 0.003
    assert quantities.equivalent_shear_strain(np.array([0, 0, 0, 0, 0, g])) == pytest.approx(2 * g / np.sqrt(3))
    # a volumetric strain has no shear part
    assert quantities.equivalent_shear_strain(np.array([e, e, e, 0, 0, 0])) == pytest.approx(0.0, abs=1e-15)
    assert quantities.volumetric_strain(np.array([e, e, e, 0, 0, 0])) == pytest.approx(3 * e)
    assert quantities.local_axial_strain(np.array([0, 0, -e, 0, 0, 0])) == pytest.approx(e)


# -- the Gauss-point rule --------------------------------------------------------------


def test_selection_picks_nearest_held_out_points():
    _, gp = mesh_and_gauss_points(elements=(2, 2, 4))
    lower, upper = np.zeros(3), np.array([0.5, 0.5, 1.0])
    candidates = np.arange(0, len(gp), 3)
    chosen = selection.select_gauss_points(gp, candidates, lower, upper)
    assert list(chosen) == list(selection.ANCHORS)
    assert len(set(chosen.values())) == 3
    taken = []
    for name, anchor in selection.anchor_positions(lower, upper).items():
        free = np.setdiff1d(candidates, taken)
        nearest = np.linalg.norm(gp[free] - anchor, axis=1).min()
        assert chosen[name] in candidates
        assert np.linalg.norm(gp[chosen[name]] - anchor) == pytest.approx(nearest)
        taken.append(chosen[name])
    # the corner point is at the top of the specimen, the centre point near mid-height
    assert gp[chosen["corner"], 2] > 0.85
    assert abs(gp[chosen["centre"], 2] - 0.5) < 0.2
    assert gp[chosen["surface"], 0] > 0.4


def test_selection_needs_three_candidates():
    _, gp = mesh_and_gauss_points()
    with pytest.raises(ValueError, match="at least 3"):
        selection.select_gauss_points(gp, [0, 1], np.zeros(3), np.ones(3))


# -- mesh, grid, cell averages ---------------------------------------------------------


def test_vtk_grid_has_the_elements_volumes():
    size, elements = (0.5, 0.5, 1.0), (2, 2, 4)
    mesh, _ = mesh_and_gauss_points(size, elements)
    t = fields.hex_elements(mesh.p.T)
    np.testing.assert_array_equal(t, mesh.t.T)
    grid = fields.vtk_grid(mesh.p.T, t)
    volumes = grid.compute_cell_sizes(length=False, area=False, volume=True).cell_data["Volume"]
    # VTK vertex order right: every hexahedron has the positive volume 0.25·0.25·0.25 m³
    np.testing.assert_allclose(volumes, 0.25**3, rtol=1e-12)
    assert grid.n_cells == 16 and grid.n_points == 3 * 3 * 5


def test_hex_elements_rejects_foreign_node_order():
    mesh = MeshHex.init_tensor(np.linspace(0, 1, 3), np.linspace(0, 1, 2), np.linspace(0, 2, 3))
    shuffled = mesh.p.T[::-1]
    with pytest.raises(fields.MeshMismatchError, match="node order"):
        fields.hex_elements(shuffled)


def test_cell_average_uses_element_times_eight_plus_q():
    gp_values = np.arange(16.0)  # element 0 -> 0..7, element 1 -> 8..15
    np.testing.assert_allclose(fields.cell_average(gp_values, 2), [3.5, 11.5])
    np.testing.assert_allclose(fields.cell_average(gp_values, 4), [1.5, 5.5, 9.5, 13.5])  # quadrilaterals: 4 each
    with pytest.raises(ValueError, match="8 or 4 each"):
        fields.cell_average(gp_values, 3)


def test_resolve_steps_counts_negative_from_the_end():
    assert fields.resolve_steps([4, 16, -1], 58) == [4, 16, 57]
    with pytest.raises(ValueError, match="analysis.field_steps.: step 70"):
        fields.resolve_steps([70], 58)


def test_colour_limits_ignore_round_off_and_include_zero():
    # a σ23 field of round-off size must not fill a colour map
    lo, hi = fields._limits(np.array([1e-13, -2e-13]), symmetric=True, floor=1e-4)
    assert (lo, hi) == (-1e-4, 1e-4)
    # a positive field is drawn from 0, so a nearly uniform field stays one colour
    assert fields._limits(np.array([4.40, 4.47]), symmetric=False, floor=1e-6) == (0.0, 4.47)


def test_vtu_series_round_trip(tmp_path):
    ds = make_run("reference", elements=(1, 1, 2))
    out = fields.write_vtu_series(ds, tmp_path / "vtk" / "reference", "path2")
    files = sorted(p.name for p in out.iterdir())
    assert files[0] == "path2.pvd" and len(files) == 1 + ds.sizes["step"]
    last = ds["step"].values[-1]
    grid = pv.read(out / f"path2_{last:04d}.vtu")
    np.testing.assert_allclose(grid.point_data["displacement"], ds["displacement"].sel(step=last).values)
    expected = ds["stress"].sel(step=last, comp="33").values.reshape(2, 8).mean(axis=1)
    np.testing.assert_allclose(grid.cell_data["stress_33"], expected)
    pvd = (out / "path2.pvd").read_text()
    assert pvd.count("<DataSet") == ds.sizes["step"] and 'timestep="57"' in pvd
    assert not (tmp_path / "vtk" / ".reference.tmp").exists()


# -- tables ----------------------------------------------------------------------------


def test_describe_run_reads_table4_columns_from_path2():
    ds = make_run("reference", wall_per_step=2.0)
    row = tables.describe_run(ds, "FEM–DEM", "Path2")
    # the paper's Table 4: 57 load steps, unloading from step 10, reloading from step 16
    assert (row["load_steps"], row["unloading_step"], row["reloading_step"]) == (57, 10, 16)
    assert row["rves"] == 16
    assert row["wall_time_s"] == pytest.approx(57 * 2.0)
    assert row["newton_iterations"] == int(ds["newton_iterations"].values[1:].sum())
    # the same numbers come from the load path itself
    assert tables.load_path_summary(PATH2) == {"load_steps": 57, "unloading_step": 10, "reloading_step": 16}


def test_wall_time_prefers_the_solvers_total():
    ds = make_run("reference", wall_per_step=1.0)
    ds.attrs["time_run_s"] = 70.0
    assert tables.run_wall_time(ds) == 70.0


def test_speedup_table_with_paper_rows():
    ref = tables.describe_run(make_run("reference", wall_per_step=10.0), "FEM–DEM", "Path2")
    ml = tables.describe_run(make_run("ml", wall_per_step=0.1), "FEM–ML", "Path2")
    paper = {"source": "paper", "reference_method": "FEM–DEM", "surrogate_method": "FEM–ML", "path": "Path2",
             "load_steps": 57, "unloading_step": 10, "reloading_step": 16, "rves": 2000,
             "reference_hours": 24.8, "surrogate_hours": 0.2, "speedup": 125}
    table = tables.speedup_table([ref, ml], paper)
    assert list(table.columns) == list(tables.SPEEDUP_COLUMNS)
    assert table["speedup"].tolist()[:2] == pytest.approx([1.0, 100.0])
    paper_rows = table[table["source"] == "paper"]
    assert paper_rows["wall_time_h"].tolist() == pytest.approx([24.8, 0.2])
    assert paper_rows["speedup"].tolist() == pytest.approx([1.0, 125.0])
    assert paper_rows["rves"].tolist() == [2000, 2000]


def test_accuracy_row_known_offsets():
    ref = make_run("reference")
    run = ref.copy(deep=True)
    run["stress"] = run["stress"] + 1e3  # +1 kPa everywhere
    run["top_force"] = run["top_force"] * 1.02
    row = tables.accuracy_row(ref, run, "offset", "Path2", train_gp=[0, 1, 2], heldout_gp=[3, 4])
    assert row["stress_mae_heldout_kpa"] == pytest.approx(1.0)
    assert row["stress_mae_train_kpa"] == pytest.approx(1.0)
    assert row["top_force_max_rel_pct"] == pytest.approx(2.0)
    assert row["volumetric_strain_max_abs_pct"] == pytest.approx(0.0)
    same = tables.accuracy_row(ref, ref, "same", "Path2", [0], [1])
    assert same["stress_mae_all_kpa"] == 0.0 and same["top_force_rms_rel_pct"] == 0.0


def test_html_table_greys_reference_rows(tmp_path):
    table = pd.DataFrame({"method": ["a", "paper"], "wall_time_s": [1.5, 89280.0]})
    page = tables.write_html_table(table, tmp_path / "t.html", title="T", reference_rows=[1]).read_text()
    assert page.count("<tr") == 3 and 'class="reference"' in page and "<td>89280</td>" in page


# -- what ran: symmetry and uniform field ----------------------------------------------


def quarter_run(**attrs):
    """A run of the quarter mesh (1×1×2 elements, 16 Gauss points) of a 2×2×2 specimen."""
    ds = make_run("reference", elements=(1, 1, 2))
    ds.attrs.update({"specimen_elements": [2, 2, 2], "mesh_elements": [1, 1, 2], "symmetry": "quarter",
                     "modelled_fraction": 0.25, "uniform_field": 0, "gauss_points_per_element": 8, **attrs})
    return ds


def test_a_quarter_symmetry_run_counts_the_gauss_points_of_its_mesh():
    ds = quarter_run(method="dem")
    assert tables.describe_run(ds, "FEM–DEM", "Path2")["rves"] == 16
    reduction = tables.model_reduction(ds)
    assert reduction == {"specimen_elements": [2, 2, 2], "mesh_elements": [1, 1, 2], "symmetry": "quarter",
                         "modelled_fraction": 0.25, "uniform_field": False, "gauss_points_full_specimen": 64,
                         "gauss_points_modelled": 16, "material_points_evaluated": 16}


def test_a_uniform_field_reference_run_evaluated_one_rve():
    """One material point stands for the 16 Gauss points of a reference run; FEM–ML builds its
    surrogate set with one point per Gauss point, so its row keeps all 16."""
    dem = make_run("reference")
    dem.attrs.update({"method": "dem", "uniform_field": 1, "symmetry": "none", "mesh_elements": [1, 1, 2],
                      "specimen_elements": [1, 1, 2]})
    assert tables.describe_run(dem, "FEM–DEM", "Path2")["rves"] == 1
    assert tables.model_reduction(dem)["material_points_evaluated"] == 1
    assert tables.model_reduction(dem)["gauss_points_modelled"] == 16
    ml = dem.copy()
    ml.attrs["method"] = "fem_ml_nn"
    assert tables.describe_run(ml, "FEM–ML", "Path2")["rves"] == 16
    # a run file that records its material points is taken at its word
    ml.attrs["material_points"] = 1
    assert tables.material_points_evaluated(ml) == 1


def test_an_old_run_file_without_the_attrs_is_the_full_specimen():
    ds = make_run("reference")
    assert tables.model_reduction(ds)["symmetry"] == "none"
    assert tables.model_reduction(ds)["material_points_evaluated"] == 16


# -- numbers as people read them -------------------------------------------------------


@pytest.mark.parametrize("value, number, ratio, duration", [
    (0.247, "0.247", "0.247×", "0.247 s"),
    (563.2, "563", "563×", "563 s (9.4 min)"),
    (2660.3, "2,660", "2,660×", "2,660 s (44 min)"),
    (1.2e5, "120,000", "120,000×", "120,000 s (33 h)"),
    (0.9996, "1.00", "1.00×", "1.00 s"),
    (12.34, "12.3", "12.3×", "12.3 s"),
])
def test_readable_numbers(value, number, ratio, duration):
    from granular_multiscale.analysis import products

    assert products.readable_number(value) == number
    assert products.readable_ratio(value) == ratio
    assert products.readable_duration(value) == duration


def test_readable_numbers_of_nothing():
    from granular_multiscale.analysis import products

    assert products.readable_number(float("nan")) == "n/a" and products.readable_number(None) == "n/a"
    assert products.readable_number(0.0) == "0" and products.readable_number(-2660.3) == "-2,660"
    assert products.readable_duration(-1.0) == "n/a" and products.readable_ratio(float("inf")) == "n/a"


# -- the full cost of an answer --------------------------------------------------------


def test_break_even_is_the_smallest_number_of_runs_that_repays_the_surrogate():
    # 2·0.5 + 1000 > 2·500, 3·0.5 + 1000 <= 3·500
    assert tables.break_even_runs(1000.0, 500.0, 0.5) == 3
    assert tables.break_even_runs(999.0, 500.0, 0.5) == 2  # 2·0.5 + 999 = 1000 = 2·500 exactly
    assert tables.break_even_runs(0.0, 5.0, 1.0) == 1
    assert tables.break_even_runs(10.0, 1.0, 2.0) is None  # the surrogate is slower: never
    assert tables.break_even_runs(10.0, 1.0, 1.0) is None
    with pytest.raises(ValueError, match="finite times"):
        tables.break_even_runs(float("nan"), 1.0, 0.1)


def write_cost_inputs(tmp_path, *, surrogate_steps=None):
    """Speedup table of a 500 s reference and a 0.5 s FEM–ML run, a 400 s training run, an RVE
    summary of two packings (60 + 40 s), and benchmarks of 20, 300 and 180 s."""
    import json

    from granular_multiscale.data import write_run

    ref = make_run("reference")
    ref.attrs["time_run_s"] = 500.0
    ml = make_run("ml")
    ml.attrs["time_run_s"] = 0.5
    if surrogate_steps is not None:
        ml = ml.isel(step=slice(0, surrogate_steps + 1))
        ml.attrs["completed"] = 0
    rows = [tables.describe_run(ref, "FEM–DEM (150 spheres)", "Path2"), tables.describe_run(ml, "FEM–ML (nn tangent)", "Path2")]
    tables.write_csv(tables.speedup_table(rows), tmp_path / "speedup.csv")
    training = make_run("reference", path=PATH2)
    training.attrs["time_run_s"] = 400.0
    write_run(training, tmp_path / "path1.h5", {})
    (tmp_path / "summary.json").write_text(json.dumps({"packings": [{"wall_time": 60.0}, {"wall_time": 40.0}]}))
    for name, seconds in (("dataset", 20.0), ("train_sigma", 300.0), ("train_tangent", 180.0)):
        (tmp_path / f"{name}.tsv").write_text(f"s\th:m:s\tmax_rss\n{seconds}\t0:00:00\t100.0\n")
    return [("RVE preparation", "rve_summary", tmp_path / "summary.json"),
            ("reference run of Path1", "run", tmp_path / "path1.h5"),
            ("dataset", "benchmark", tmp_path / "dataset.tsv"),
            ("training NNσ", "benchmark", tmp_path / "train_sigma.tsv"),
            ("training ND", "benchmark", tmp_path / "train_tangent.tsv")]


def test_surrogate_cost_table_and_break_even(tmp_path):
    from granular_multiscale.analysis import products

    items = write_cost_inputs(tmp_path)
    table = products.make_surrogate_cost(items, tmp_path / "speedup.csv", tmp_path / "cost.csv", tmp_path / "cost.html",
                                         reference_label="FEM–DEM (150 spheres)", surrogate_label="FEM–ML (nn tangent)",
                                         path_label="Path2")
    saved = pd.read_csv(tmp_path / "cost.csv")
    assert list(saved.columns) == list(tables.COST_COLUMNS)
    costs = saved[saved["kind"] == "surrogate cost"]
    assert costs["wall_time_s"].tolist() == pytest.approx([100.0, 400.0, 20.0, 300.0, 180.0])
    total = saved[saved["kind"] == "surrogate cost total"]["wall_time_s"]
    assert total.tolist() == pytest.approx([1000.0])
    answers = saved[saved["kind"] == "one answer"]["wall_time_s"]
    assert answers.tolist() == pytest.approx([500.0, 0.5])
    # 1000 s of surrogate at a saving of 499.5 s per answer: 3 answers
    even = saved[saved["kind"] == "break-even"]
    assert even["runs"].tolist() == [3, 3]
    assert even["wall_time_s"].tolist() == pytest.approx([3 * 0.5 + 1000.0, 3 * 500.0])
    assert table["wall_time_h"].iloc[5] == pytest.approx(1000.0 / 3600)
    page = (tmp_path / "cost.html").read_text()
    assert "from 3 FEM–ML runs on" in page and "1,000 s (17 min)" in page
    assert "<td>train_sigma.tsv</td>" in page and str(tmp_path) not in page  # files below their folder

    headline = products.make_headline(tmp_path / "speedup.csv", write_accuracy(tmp_path), tmp_path / "headline.json",
                                      config=CONFIG, reference_label="FEM–DEM (150 spheres)",
                                      surrogate_label="FEM–ML (nn tangent)", ablation_label=None,
                                      cost_csv=tmp_path / "cost.csv")
    assert headline["surrogate_cost_s"] == pytest.approx(1000.0) and headline["break_even_runs"] == 3
    assert headline["display"]["surrogate_cost"] == "1,000 s (17 min)"
    assert headline["display"]["break_even_runs"] == "3"
    assert headline["display"]["speedup"] == "1,000×"  # 500 s / 0.5 s
    assert headline["display"]["surrogate_cost_items"][0] == "RVE preparation 100 s"


def test_a_surrogate_run_that_stopped_counts_its_time_per_step_for_the_whole_path(tmp_path):
    from granular_multiscale.analysis import products

    items = write_cost_inputs(tmp_path, surrogate_steps=19)  # 0.5 s for 19 of the 57 steps
    products.make_surrogate_cost(items, tmp_path / "speedup.csv", tmp_path / "cost.csv", tmp_path / "cost.html",
                                 reference_label="FEM–DEM (150 spheres)", surrogate_label="FEM–ML (nn tangent)",
                                 path_label="Path2")
    saved = pd.read_csv(tmp_path / "cost.csv")
    assert saved[saved["kind"] == "one answer"]["wall_time_s"].tolist() == pytest.approx([500.0, 1.5])
    assert saved[saved["kind"] == "break-even"]["runs"].tolist() == [3, 3]  # 1000 / 498.5
    assert "stopped early" in (tmp_path / "cost.html").read_text()


def test_surrogate_cost_names_a_bad_file(tmp_path):
    from granular_multiscale.analysis import products

    items = write_cost_inputs(tmp_path)
    (tmp_path / "train_sigma.tsv").write_text("h:m:s\n0:00:01\n")
    with pytest.raises(ValueError, match=r"train_sigma\.tsv has no column 's'"):
        products.make_surrogate_cost(items, tmp_path / "speedup.csv", tmp_path / "c.csv", tmp_path / "c.html",
                                     reference_label="FEM–DEM (150 spheres)", surrogate_label="FEM–ML (nn tangent)",
                                     path_label="Path2")
    (tmp_path / "summary.json").write_text('{"n_packings": 1}')
    with pytest.raises(ValueError, match=r"summary\.json lacks 'packings'"):
        tables.rve_preparation_seconds(tmp_path / "summary.json")
    with pytest.raises(ValueError, match="no row for 'FEM–ML, other'"):
        products.make_surrogate_cost(items[1:2], tmp_path / "speedup.csv", tmp_path / "c.csv", tmp_path / "c.html",
                                     reference_label="FEM–DEM (150 spheres)", surrogate_label="FEM–ML, other",
                                     path_label="Path2")


CONFIG = {"output_dir": "results/x", "reference_material": "dem", "validation_path": "path2", "training_path": "path1",
          "specimen": {"elements": [2, 2, 2], "symmetry": "quarter", "uniform_field": False}, "dem": {"n_spheres": 150}}


def write_accuracy(tmp_path):
    pd.DataFrame([{"method": "FEM–ML (nn tangent)", "top_force_max_rel_pct": 2.414,
                   "stress_mae_heldout_kpa": 1.9512}]).to_csv(tmp_path / "accuracy.csv", index=False)
    return tmp_path / "accuracy.csv"


@pytest.mark.parametrize("uniform", [False, True])
def test_headline_states_what_ran_from_the_reference_run(tmp_path, uniform):
    """Quarter symmetry of a 2×2×2 specimen: 16 of its 64 Gauss points modelled; with a uniform
    field one RVE stands for them."""
    from granular_multiscale.analysis import products
    from granular_multiscale.data import write_run

    write_cost_inputs(tmp_path)
    write_run(quarter_run(method="dem", uniform_field=int(uniform)), tmp_path / "path2.h5", {})
    headline = products.make_headline(tmp_path / "speedup.csv", write_accuracy(tmp_path), tmp_path / "headline.json",
                                      config=CONFIG, reference_label="FEM–DEM (150 spheres)",
                                      surrogate_label="FEM–ML (nn tangent)", ablation_label=None,
                                      reference_run=tmp_path / "path2.h5")
    assert headline["gauss_points"] == 64 and headline["gauss_points_modelled"] == 16
    assert headline["symmetry"] == "quarter" and headline["modelled_fraction"] == 0.25
    assert headline["uniform_field"] is uniform and headline["mesh_elements"] == [1, 1, 2]
    assert headline["material_points_evaluated"] == (1 if uniform else 16)
    assert headline["surrogate_points_evaluated"] == 16
    assert headline["display"]["top_force_max_rel_pct"] == "2.41 %"
    assert headline["display"]["stress_mae_heldout_kpa"] == "1.95 kPa"
    assert headline["display"]["reference_wall_time"] == "500 s (8.3 min)"
    # without the run file, the same from the config
    from_config = products.make_headline(tmp_path / "speedup.csv", tmp_path / "accuracy.csv", tmp_path / "h2.json",
                                         config={**CONFIG, "specimen": {**CONFIG["specimen"], "uniform_field": uniform}},
                                         reference_label="FEM–DEM (150 spheres)",
                                         surrogate_label="FEM–ML (nn tangent)", ablation_label=None)
    for key in ("gauss_points_modelled", "material_points_evaluated", "mesh_elements", "symmetry", "uniform_field"):
        assert from_config[key] == headline[key], key



def plain_text(page: str) -> str:
    """The text of an HTML page, tags dropped and whitespace collapsed."""
    import re

    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", "", page.split("<body>", 1)[1]))


def test_the_headline_page_states_the_numbers_of_headline_json(tmp_path):
    """The report's headline page (rule headline writes it with tables/headline.json): what ran,
    the reference's tolerance, the machine, speedup, cost, break-even and errors, each the number
    of headline.json as headline_display writes it."""
    import json

    from granular_multiscale import integrity
    from granular_multiscale.analysis import products
    from granular_multiscale.data import write_run

    products.make_surrogate_cost(write_cost_inputs(tmp_path), tmp_path / "speedup.csv", tmp_path / "cost.csv",
                                 tmp_path / "cost.html", reference_label="FEM–DEM (150 spheres)",
                                 surrogate_label="FEM–ML (nn tangent)", path_label="Path2")
    run = quarter_run(method="dem", uniform_field=1, newton_tolerance=2e-3, newton_predictor="extrapolate",
                      newton_acceleration="anderson")
    steps = run.sizes["step"]
    run["material_evaluations"] = ("step", np.full(steps, 3))
    run["cutbacks"] = ("step", np.zeros(steps, dtype=int))
    run["residual_relative"] = ("step", np.linspace(0.0, 1.87e-3, steps))
    write_run(run, tmp_path / "path2.h5", {})
    pd.DataFrame([{"method": "FEM–ML (nn tangent)", "top_force_max_rel_pct": 2.414, "stress_mae_heldout_kpa": 1.9512},
                  {"method": "FEM–ML, no history", "top_force_max_rel_pct": 5.02, "stress_mae_heldout_kpa": 3.01}]
                 ).to_csv(tmp_path / "accuracy.csv", index=False)
    products.make_headline(tmp_path / "speedup.csv", tmp_path / "accuracy.csv", tmp_path / "headline.json",
                           config={**CONFIG, "specimen": {**CONFIG["specimen"], "uniform_field": True}},
                           reference_label="FEM–DEM (150 spheres)", surrogate_label="FEM–ML (nn tangent)",
                           ablation_label="FEM–ML, no history", reference_run=tmp_path / "path2.h5",
                           cost_csv=tmp_path / "cost.csv", page=tmp_path / "headline.html")
    integrity.verify(tmp_path / "headline.html")  # written whole, with its checksum
    h = json.loads((tmp_path / "headline.json").read_text())
    d = h["display"]
    text = plain_text((tmp_path / "headline.html").read_text())
    assert "e+0" not in text and "e-0" not in text and "None" not in text and "n/a" not in text
    # the numbers of headline.json, as its display writes them
    assert (d["speedup"], d["surrogate_wall_time"], d["reference_wall_time"]) == ("1,000×", "0.500 s", "500 s (8.3 min)")
    assert (f"Speedup {d['speedup']} for one answer: FEM–ML (nn tangent) took {d['surrogate_wall_time']}, "
            f"FEM–DEM (150 spheres) {d['reference_wall_time']}") in text
    assert f"Making the surrogate took {d['surrogate_cost']}: RVE preparation 100 s; reference run of Path1 400 s" in text
    assert d["surrogate_cost"] == "1,000 s (17 min)" and h["break_even_runs"] == 3
    assert f"It pays back from {d['break_even_runs']} FEM–ML runs of path2 on" in text
    assert f"Top-force error {d['top_force_max_rel_pct']} of the peak" in text and d["top_force_max_rel_pct"] == "2.41 %"
    assert f"Held-out stress MAE {d['stress_mae_heldout_kpa']}" in text and d["stress_mae_heldout_kpa"] == "1.95 kPa"
    assert "Without history variables (FEM–ML, no history): top-force error 5.02 %, held-out stress MAE 3.01 kPa" in text
    # what ran, from the reference run: quarter symmetry, one RVE for the 16 Gauss points
    assert ("quarter symmetry (specimen.symmetry: quarter), a mesh of 1 × 1 × 2 elements with 16 of the "
            "specimen's 64 Gauss points") in text
    assert "one material point stands for all 16 Gauss points, so the reference evaluated 1 RVE;" in text
    assert "FEM–ML evaluated the surrogate at 16 points." in text
    # the reference's tolerance and residual, from its run file; its own error: where it is measured
    assert h["reference_newton"]["tolerance"] == 2e-3
    assert ("The reference was solved to a relative residual of 0.002 (largest accepted: 0.0019; extrapolate "
            "predictor, Anderson mixing).") in text
    assert "Its own error is measured by the tolerance study" in text and "snakemake -j2 tolerance_study" in text
    assert f"Measured on {h['machine']['cores']} cores of {h['machine']['cpu']}" in text


def test_the_headline_page_leaves_out_what_a_headline_lacks():
    """A headline without the reference's Newton record, the cost table, the accuracy rows and
    the ablation (an analytic reference, a FEM–ML run that stopped early): the page states what
    it has and says what it lacks, with no placeholder; with the reference's own error (a
    headline that carries reference_convergence) it states that too."""
    from granular_multiscale.analysis import products

    h = {"reference_material": "elastoplastic", "reference": "FEM, elastoplastic model (reference)",
         "surrogate": "FEM–ML (nn tangent)", "validation_path": "path2", "gauss_points": 64, "mesh_elements": [2, 2, 2],
         "symmetry": "none", "uniform_field": False, "gauss_points_modelled": 64, "material_points_evaluated": 64,
         "surrogate_points_evaluated": 64, "machine": {"cores": 2, "cpu": "Test CPU", "memory_gib": None,
                                                        "system": "Linux"},
         "reference_wall_time_s": 0.31, "surrogate_wall_time_s": 1.2, "speedup": 0.2583, "surrogate_completed": False,
         "surrogate_load_steps": 19, "reference_load_steps": 57, "top_force_max_rel_pct": None,
         "stress_mae_heldout_kpa": None, "ablation": None, "ablation_top_force_max_rel_pct": None,
         "ablation_stress_mae_heldout_kpa": None, "surrogate_cost_s": None, "surrogate_cost_items": [],
         "break_even_runs": None}
    text = plain_text(products.headline_page(h))
    assert "None" not in text and "n/a" not in text
    assert "Speedup 0.258× for one answer: FEM–ML (nn tangent) took 1.20 s, FEM, elastoplastic model (reference) 0.310 s" in text
    assert "the reference evaluated 64 material points, one per Gauss point" in text
    assert "does not record its Newton tolerance" in text
    assert "not in this headline (no surrogate cost table)" in text and "Making the surrogate" not in text
    assert "FEM–ML (nn tangent) stopped after load step 19 of 57" in text
    assert "Top-force error" not in text and "Without history variables" not in text
    assert "Measured on 2 cores of Test CPU (Linux)." in text

    h.update(surrogate_cost_s=3.0, surrogate_cost_items=[{"item": "dataset", "wall_time_s": 3.0}],
             reference_newton={"tolerance": 1e-8, "predictor": "tangent", "acceleration": "none",
                               "residual_relative_max": 3.2e-9})
    text = plain_text(products.headline_page(h))
    assert "Making the surrogate took 3.00 s: dataset 3.00 s. It never pays back here" in text
    assert "The reference is the analytic model, not FEM–DEM" in text
    assert "solved to a relative residual of 0.00000001 (largest accepted: 0.0000000032; tangent predictor)" in text
    assert "the tolerance study measures FEM–DEM runs, and this reference is the analytic model" in text
    h.update(reference_material="dem", reference_convergence={
        "variant": "default", "converged_tolerance": 5e-4, "top_force_max_pct": 0.2834,
        "volumetric_strain_max_pct": 1.216, "stress_mae_kpa": 0.1104})
    text = plain_text(products.headline_page(h))
    assert ("Its own error, measured by the tolerance study (variant default against a run to 0.0005): top force "
            "within 0.28 % of the peak, volumetric strain within 1.22 % of its peak magnitude, Gauss-point stress "
            "MAE 0.11 kPa.") in text


def test_the_reference_convergence_page_states_the_study_row_solved_like_the_reference(tmp_path):
    """Rule tolerance_study's page of the reference's own error: the study's row with the Newton
    settings of the FEM–DEM runs; none when no variant is solved so."""
    from granular_multiscale import integrity
    from granular_multiscale.analysis import products

    pd.DataFrame([
        {"variant": "loose", "tolerance": 2e-2, "predictor": "tangent", "acceleration": "none",
         "top_force_max_pct": 2.31, "volumetric_strain_max_pct": 11.8, "stress_mae_kpa": 0.9,
         "evaluations_per_step": 4.0},
        {"variant": "default", "tolerance": 2e-3, "predictor": "extrapolate", "acceleration": "anderson",
         "top_force_max_pct": 0.1734, "volumetric_strain_max_pct": 0.8123, "stress_mae_kpa": 0.0561,
         "evaluations_per_step": 3.0},
        {"variant": "tight", "tolerance": 5e-4, "predictor": "extrapolate", "acceleration": "anderson",
         "top_force_max_pct": 0.0, "volumetric_strain_max_pct": 0.0, "stress_mae_kpa": 0.0,
         "evaluations_per_step": 6.0}]).to_csv(tmp_path / "study.csv", index=False)
    newton = {"tolerance": 2e-3, "predictor": "extrapolate", "acceleration": "anderson"}
    found = products.make_reference_convergence(tmp_path / "study.csv", tmp_path / "page.html", newton=newton,
                                                study_path="Path2", reference_material="dem")
    integrity.verify(tmp_path / "page.html")
    assert found["variant"] == "default" and found["converged_tolerance"] == 5e-4
    text = plain_text((tmp_path / "page.html").read_text())
    assert ("FEM–DEM runs of this configuration are solved to a relative residual of 0.002 (extrapolate predictor, "
            "Anderson mixing;") in text
    assert ("measured by the tolerance study on Path2 (variant default against a run to 0.0005): top force within "
            "0.17 % of the peak, volumetric strain within 0.81 % of its peak magnitude, Gauss-point stress MAE "
            "0.06 kPa") in text
    assert "analytic" not in text
    missing = products.make_reference_convergence(tmp_path / "study.csv", tmp_path / "none.html",
                                                  newton=dict(newton, tolerance=1e-3), study_path="Path2",
                                                  reference_material="elastoplastic")
    text = plain_text((tmp_path / "none.html").read_text())
    assert missing is None and "No variant of the tolerance study" in text and "Its own error" not in text
    assert "This report's reference is the analytic elastoplastic model" in text


def test_runs_are_compared_on_their_load_schedule_axial_strain_or_settlement():
    """The triaxial specimen's and the biaxial test's runs share an axial-strain schedule, the
    footing's a settlement: common_steps compares whichever both runs have, and names it when it
    differs."""
    import xarray as xr

    from granular_multiscale.analysis.metrics import common_steps

    def run(**schedule):
        return xr.Dataset({name: ("step", np.asarray(values, dtype=float)) for name, values in schedule.items()})

    footing = run(load_displacement=[0.0, 1e-3, 2e-3])
    assert common_steps(footing, run(load_displacement=[0.0, 1e-3, 2e-3])).sizes["step"] == 3
    with pytest.raises(ValueError, match="load displacement schedule differs"):
        common_steps(footing, run(load_displacement=[0.0, 1e-3, 3e-3]), label="other")
    with pytest.raises(ValueError, match="axial strain schedule differs"):
        common_steps(run(axial_strain=[0, 0.01]), run(axial_strain=[0, 0.02]))
    with pytest.raises(ValueError, match="no load schedule"):
        common_steps(footing, run(axial_strain=[0.0, 0.01, 0.02]))
