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
    with pytest.raises(ValueError, match="8 each"):
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
