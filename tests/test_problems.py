"""The problems beyond the triaxial specimen: the plane-strain biaxial test and the strip footing.

Closed-form checks with the linear elastic material, localisation with the softening
elastoplastic model (no YADE), the band and angle metrics on fields whose answer is known, the
errors of bad settings, and, with real YADE RVEs, a band in the biaxial test and a resume after
kill -9 that ends bit for bit where an uninterrupted run does."""

from __future__ import annotations

import os
import pickle
import signal
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import yaml
from dem_fixtures import ROOT, packing, tiny_config

from granular_multiscale.analysis.angles import bearing_capacity_factor, element_angles
from granular_multiscale.analysis.bands import band_metrics
from granular_multiscale.config import ConfigError, validate_config
from granular_multiscale.data import read_run
from granular_multiscale.drivers.problems import analytic_material, check_problems, dem_packings, problem_and_path
from granular_multiscale.drivers.reference import run_fem_reference
from granular_multiscale.fem import make_problem
from granular_multiscale.fem.biaxial import BiaxialProblem, ProblemConfigError
from granular_multiscale.fem.footing import FootingProblem
from granular_multiscale.fem.newton import ConvergenceError
from granular_multiscale.materials import LinearElastic
from granular_multiscale.materials.elastoplastic import SOFTENING
from granular_multiscale.paths import LoadPath

P0 = 1.0e5
E, NU = 5.0e7, 0.25
ISOTROPIC = [-P0, -P0, -P0, 0.0, 0.0, 0.0]


def elastic(problem) -> LinearElastic:
    return LinearElastic(problem.n_material_points, E, NU, initial_stress=ISOTROPIC)


def softening_config(tmp_path: Path, **sections) -> dict:
    """The tiny config with the softening elastoplastic model, and the given section overrides."""
    config = tiny_config(tmp_path, {"path1": [[2, 0.002]]})
    config["reference_material"] = "elastoplastic"
    config["elastoplastic"].update(SOFTENING)
    config["newton"]["max_cutbacks"] = 6
    for name, values in sections.items():
        config[name].update(values)
    return validate_config(config)


# ------------------------------------------------------------------------ closed form
def test_biaxial_elastic_plane_strain_is_the_closed_form():
    """A homogeneous elastic specimen in the x–z plane: uniform plane-strain field, ε_yy = 0, the
    platen force and the lateral strain of plane-strain elasticity (E' = E/(1 − ν²), ν' = ν/(1 − ν)),
    the out-of-plane σ_yy = −p0 + ν Δ(σxx + σzz)."""
    problem = BiaxialProblem(size=(0.05, 0.1), elements=(3, 6), weak_zone=None)
    ds = problem.run(elastic(problem), LoadPath("p", ((4, 0.004),)), progress=False)
    strain, stress = ds.strain.values, ds.stress.values
    assert np.abs(strain[:, :, [1, 3, 5]]).max() == 0.0  # ε_yy = γ_yz = γ_xy = 0 at every Gauss point
    axial = ds.axial_strain.values
    e_plane, nu_plane = E / (1 - NU**2), NU / (1 - NU)
    width = 0.05
    np.testing.assert_allclose(ds.load_force.values, P0 * width + e_plane * axial * width, rtol=1e-9)
    np.testing.assert_allclose(ds.top_force.values, -ds.load_force.values, rtol=0)
    np.testing.assert_allclose(ds.lateral_strain.values, nu_plane * axial, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(strain[-1, :, 2], -axial[-1], rtol=1e-9)
    d_sigma = stress[-1, :, 0] + stress[-1, :, 2] + 2 * P0
    np.testing.assert_allclose(stress[-1, :, 1], -P0 + NU * d_sigma, rtol=1e-9)
    assert np.abs(ds.gp_position.sel(xyz="y").values).max() == 0.0
    assert np.ptp(stress[-1], axis=0).max() < 1e-6 * P0  # homogeneous
    assert ds.attrs["plane_strain"] == 1 and ds.sizes["gp"] == 72 and ds.attrs["problem"] == "biaxial"
    np.testing.assert_allclose(ds.load_displacement.values, axial * 0.1, rtol=0)


@pytest.mark.parametrize("element", ["quad8", "quad4"])
def test_plane_strain_elements_integrate_exactly(element):
    """Element areas and Gauss-point counts: 2 × 2 points per quadrilateral, weights summing to W × H."""
    problem = BiaxialProblem(size=(0.05, 0.1), elements=(2, 4), element=element, weak_zone=None)
    assert problem.ops.points_per_element == 4 and problem.n_gauss_points == 32
    assert problem.ops.dV.sum() == pytest.approx(0.005, rel=1e-12)
    assert problem.ops.n_nodes == (21 + 16 if element == "quad8" else 15)


def test_footing_starts_in_equilibrium_and_its_pressure_rises():
    """At zero settlement the consolidated state balances the surcharge (pressure = q0); pushing the
    footing raises the pressure at every step."""
    problem = FootingProblem()
    ds = problem.run(elastic(problem), LoadPath("f", ((5, 0.05),)), progress=False)
    q = ds.footing_pressure.values
    assert q[0] == pytest.approx(P0, rel=1e-9)
    assert ds.residual_relative.values[0] < 1e-12
    assert np.all(np.diff(q) > 0)
    assert ds.attrs["modelled_fraction"] == 0.5 and ds.attrs["surcharge_Pa"] == P0
    np.testing.assert_allclose(ds.load_force.values, q * 0.1, rtol=1e-12)


def test_footing_half_domain_equals_the_full_domain(tmp_path):
    """The half model (symmetry plane) gives the full domain's footing pressure, and the full
    domain's nodes on the plane x = 0 move only vertically (softening elastoplastic model)."""
    config = softening_config(tmp_path, footing={"load_paths": {"f": {"segments": [[6, 0.06]]}}})
    half = run_fem_reference(config, "f", tmp_path / "half.h5", problem="footing")
    config["footing"]["symmetry"] = "none"
    full = run_fem_reference(config, "f", tmp_path / "full.h5", problem="footing")
    assert full.sizes["gp"] == 2 * half.sizes["gp"]
    np.testing.assert_allclose(full.footing_pressure.values, half.footing_pressure.values, rtol=1e-6)
    plane = np.abs(full.node_position.values[:, 0]) < 1e-12
    ux = full.displacement.sel(xyz="x").values[:, plane]
    uz = full.displacement.sel(xyz="z").values[:, plane]
    assert np.abs(ux).max() < 1e-9 * np.abs(uz).max()
    assert np.all(np.diff(half.footing_pressure.values) > 0)
    assert half.footing_pressure.values[-1] > 3 * P0  # several times the surcharge at 6 % of B


def test_the_load_force_in_virtual_work_is_the_reaction_in_equilibrium_and_weighs_every_point(tmp_path):
    """The virtual field is the elastic one of a unit platen displacement: on the biaxial specimen
    with smooth platens the homogeneous v_z = z/H, 1 at the loaded dofs, 0 at the fixed ones. At every
    converged state of the softening biaxial and footing runs the force in virtual work is the run's
    reaction (to the Newton tolerance). A stress change at one point away from the loaded boundary
    leaves the reaction at the loaded dofs alone and moves the virtual-work force by exactly
    dV · ε(v)·δσ there."""
    from granular_multiscale.fem.assembly import ENGINEERING_FACTOR

    problem = BiaxialProblem(size=(0.05, 0.1), elements=(3, 6), weak_zone=None)
    v = problem.virtual_load_field()
    z = problem.ops.mesh_node_positions[:, 1]
    np.testing.assert_allclose(v[problem.ops.node_dofs(np.arange(problem.ops.n_nodes), 1)], z / 0.1, atol=1e-12)
    assert np.all(v[problem.loaded_dofs] == 1.0) and np.all(v[problem.fixed_dofs] == 0.0)

    config = softening_config(tmp_path, biaxial={"elements": [3, 6]},
                              footing={"load_paths": {"f": {"segments": [[4, 0.04]]}}})
    stresses = {}
    for name, path in (("biaxial", "biaxial"), ("footing", "f")):
        run = run_fem_reference(config, path, tmp_path / f"{name}.h5", problem=name)
        problem = make_problem(config, name)
        stresses[name] = run.stress.transpose("step", "gp", "comp").values
        in_virtual_work = np.array([problem.load_force_in_virtual_work(s) for s in stresses[name]])
        force = run.load_force.values
        assert np.abs(in_virtual_work - force).max() < config["newton"]["tolerance"] * np.abs(force).max(), name

    problem = make_problem(config, "biaxial")
    sigma = stresses["biaxial"][-1]
    lowest = int(np.argmin(problem.gp_positions[:, 2]))  # the Gauss point nearest the fixed bottom
    bump = np.zeros_like(sigma)
    bump[lowest, 2] = 1e4
    reaction = lambda s: problem.load_force(problem.ops.internal_force(s) - problem.f_ext)  # noqa: E731
    assert reaction(sigma + bump) == pytest.approx(reaction(sigma), rel=1e-14)  # it touches no loaded dof
    strain_of_v = problem.ops.strain(problem.virtual_load_field())[lowest] * ENGINEERING_FACTOR
    expected = -problem.ops.dV.ravel()[lowest] * strain_of_v @ bump[lowest]
    change = problem.load_force_in_virtual_work(sigma + bump) - problem.load_force_in_virtual_work(sigma)
    assert change == pytest.approx(expected, rel=1e-9) and abs(change) > 1e-3 * 1e4 * problem.ops.dV.ravel()[lowest]


def test_the_networks_along_a_runs_own_strains_give_back_that_run(tmp_path):
    """FEM–ML's networks driven along the strains of FEM–ML's own biaxial run (no FEM) answer its
    stresses and, in virtual work, its platen force (to its Newton tolerance): so against a FEM–DEM
    reference the driven run's error is the material's alone. Its file keeps the reference's
    kinematics and says it ran no Newton and no DEM; a reference on another mesh is refused.
    FEM–ML solved as the reference is takes FEM–DEM's Newton settings (tiny.yaml's biaxial: 5e-2,
    the extrapolating predictor, Anderson) and ND for its tangent."""
    import torch

    from granular_multiscale.analysis.problem_surrogate import comparison_table
    from granular_multiscale.data import write_run
    from granular_multiscale.config import dem_newton_config
    from granular_multiscale.drivers.fem_ml import fem_ml_config, run_along_reference, run_fem_ml
    from granular_multiscale.materials.elastoplastic import Elastoplastic
    from granular_multiscale.paths import load_paths_from_config
    from granular_multiscale.surrogate.dataset import build_dataset
    from granular_multiscale.surrogate.synthetic import material_point_run, triaxial_strain_paths
    from granular_multiscale.surrogate.training import train

    torch.set_num_threads(1)
    config = tiny_config(tmp_path / "o", {"path1": [[2, 0.002]]})
    config["biaxial"]["load_paths"] = {"p": {"segments": [[3, 0.006]]}}
    config["surrogate"].update(newton={}, ensemble_size=2, epochs=150, learning_rate=5e-3, batch_size=256)
    path = load_paths_from_config(config)["path1"]
    run = material_point_run(Elastoplastic.from_config(12, config), triaxial_strain_paths(path, 12, seed=2), path)
    data = build_dataset(run, 0.75, seed=0)
    for kind in ("sigma", "tangent"):
        train(*data, kind, config["surrogate"], seed=0, config=config)[0].save(tmp_path / f"{kind}.pt")
    ml = run_fem_ml(config, "p", tmp_path / "sigma.pt", None, "autodiff", progress=False, problem="biaxial")
    assert int(ml.cutbacks.sum()) == 0  # one commit per step, as the driven run makes
    assert ml.attrs["newton_settings_of"] == "fem_ml" and ml.attrs["newton_tolerance"] == config["newton"]["tolerance"]

    as_reference = run_fem_ml(config, "p", tmp_path / "sigma.pt", tmp_path / "tangent.pt", "nn", progress=False,
                              problem="biaxial", solver="reference", allow_partial=True)
    solved = dem_newton_config(config, "biaxial")["newton"]
    assert fem_ml_config(config, "reference", "biaxial")["newton"] == solved and solved["tolerance"] == 0.05
    assert as_reference.attrs["newton_settings_of"] == "reference" and as_reference.attrs["method"] == "fem_ml_nn"
    assert (as_reference.attrs["newton_tolerance"], as_reference.attrs["newton_predictor"],
            as_reference.attrs["newton_acceleration"]) == (0.05, solved["predictor"], solved["acceleration"])
    assert as_reference.attrs["completed"] == 1 and as_reference.residual_relative.values.max() <= 0.05
    with pytest.raises(ValueError, match="solver settings must be one of"):
        fem_ml_config(config, "dem", "biaxial")

    driven = run_along_reference(config, ml, tmp_path / "sigma.pt", None, "autodiff", "biaxial")
    write_run(driven, tmp_path / "driven.h5", config)
    driven = read_run(tmp_path / "driven.h5")
    np.testing.assert_allclose(driven.stress.values, ml.stress.values, rtol=0, atol=1e-9 * np.abs(ml.stress.values).max())
    np.testing.assert_allclose(driven.stress_spread.values, ml.stress_spread.values, rtol=1e-9, atol=1e-6)
    tolerance = config["surrogate"]["newton"].get("tolerance", config["newton"]["tolerance"])
    force = ml.load_force.values
    assert np.abs(driven.load_force.values - force).max() < tolerance * np.abs(force).max()
    np.testing.assert_array_equal(driven.top_force.values, -driven.load_force.values)
    for name in ("strain", "displacement", "volumetric_strain", "axial_strain", "lateral_strain"):
        np.testing.assert_array_equal(driven[name].values, ml[name].values, err_msg=name)
    assert driven.attrs["method"] == "fem_ml_driven_autodiff" and driven.attrs["driven_along"] == "fem_ml_autodiff"
    assert driven.newton_iterations.values.sum() == 0 and driven.attrs["dem_particle_steps"] == 0
    row = comparison_table(ml, {"driven": driven}).set_index("run").loc["driven"]
    assert row["force: largest error (% of peak)"] < 100 * tolerance
    assert row["volumetric strain: largest error (% of its peak)"] == 0

    config["biaxial"]["elements"] = [3, 6]
    with pytest.raises(ValueError, match="not on the mesh of the config's 'biaxial' section"):
        run_along_reference(config, ml, tmp_path / "sigma.pt", None, "autodiff", "biaxial")


# ------------------------------------------------------------------------ localisation
def test_biaxial_localises_in_a_band_from_the_weak_zone(tmp_path):
    """Softening model, 3 × 6 quad8, config/tiny.yaml's path (to 7 %): with the weak zone a band
    forms (ratio of its shear strain to the specimen's ≥ 2; measured 2.30, inclined at 40.5°, onset
    at 4.8 %, the force peaking at 3 %); without it the specimen stays uniform (ratio 1)."""
    config = softening_config(tmp_path, biaxial={"elements": [3, 6]})
    weak = run_fem_reference(config, "biaxial", tmp_path / "weak.h5", problem="biaxial")
    m = band_metrics(weak)
    assert m["band_ratio"] >= 2.0
    assert 40 <= m["inclination_deg"] <= 60
    assert 0.028 < m["onset_load"] < 0.08  # after the peak of the force, before the end
    assert weak.load_force.values[-1] < 0.9 * weak.load_force.max()
    config["biaxial"]["weak_zone"] = None
    uniform = run_fem_reference(config, "biaxial", tmp_path / "uniform.h5", problem="biaxial")
    assert band_metrics(uniform)["band_ratio"] == pytest.approx(1.0, abs=1e-6)


def test_comparison_table_measures_errors_in_the_band_and_under_the_footing(tmp_path):
    """The surrogate's table against known differences: a run compared with itself has no error; a
    run whose stress is 10 % off inside the band only shows that error there and none outside; the
    footing's zone is the soil under it down to one footing width."""
    from granular_multiscale.analysis.problem_surrogate import comparison_table, error_map_figure, zones

    config = softening_config(tmp_path, biaxial={"elements": [3, 6]})
    reference = run_fem_reference(config, "biaxial", tmp_path / "weak.h5", problem="biaxial")
    band, inside, _ = zones(reference)
    assert inside == "in the band" and 0 < band.sum() < band.size
    off = reference.copy(deep=True)
    off["stress"].values[:, band] *= 1.1  # (step, gp, comp)
    off["load_force"].values[:] *= 1.02
    table = comparison_table(reference, {"itself": reference, "off": off}).set_index("run")
    assert (table.loc["itself", ["force: largest error (% of peak)", "stress MAE (kPa)"]] == 0).all()
    assert table.loc["itself", "inclination − reference (deg)"] == 0
    assert table.loc["off", "force: largest error (% of peak)"] == pytest.approx(2.0, rel=1e-9)
    expected = 0.1 * 1e-3 * np.abs(reference.stress.values[:, band]).mean()
    assert table.loc["off", "stress MAE in the band (kPa)"] == pytest.approx(expected, rel=1e-9)
    assert table.loc["off", "stress MAE outside the band (kPa)"] == 0
    assert table.loc["off", "steps reached"] == "14 of 14"
    stopped = comparison_table(reference, {"stopped": off.isel(step=slice(0, 5))}).set_index("run")
    assert stopped.loc["stopped", "steps reached"] == "4 of 14"
    from granular_multiscale.analysis.problems import response_figure

    drawn = response_figure({"reference": reference, "off": off}, tmp_path / "response.png", title="t")
    x, force = drawn["force"]["reference"]
    np.testing.assert_array_equal(x, 100 * reference.axial_strain.values)  # against the axial strain in %
    np.testing.assert_allclose(drawn["force"]["off"][1], 1.02 * force, rtol=1e-12)  # the run's own force
    np.testing.assert_array_equal(drawn["volumetric strain"]["off"][1], 100 * off.volumetric_strain.values)
    assert plt_image_has_colour(tmp_path / "response.png")
    drawn = error_map_figure(reference, {"off": off, "stopped": off.isel(step=slice(0, 5))}, tmp_path / "map.png",
                             title="t")
    assert plt_image_has_colour(tmp_path / "map.png")
    peak, last = int(np.argmax(reference.load_force.values)), reference.sizes["step"] - 1
    assert sorted(drawn["off"]) == sorted({peak, last}) and sorted(drawn["stopped"]) == [s for s in (peak,) if s < 5]
    p0 = reference.attrs["confining_pressure_Pa"]
    for step, shown in drawn["off"].items():  # 10 % of ‖σ_ref‖ / p0 in the band, nothing outside it
        sigma = reference.stress.values[step]  # Voigt: the three shears count twice in the tensor norm
        expected = 0.1 * np.sqrt((sigma[:, :3] ** 2).sum(axis=-1) + 2 * (sigma[:, 3:] ** 2).sum(axis=-1)) / p0
        np.testing.assert_allclose(shown["error"][band], expected[band], rtol=1e-12)
        assert np.all(shown["error"][~band] == 0) and shown["dem_points"].size == 0

    config = softening_config(tmp_path, footing={"load_paths": {"f": {"segments": [[2, 0.02]]}}})
    footing = run_fem_reference(config, "f", tmp_path / "footing.h5", problem="footing")
    under, inside, outside = zones(footing)
    xz = footing.gp_position.values[:, [0, 2]]
    depth = footing.node_position.values[:, 2].max() - xz[:, 1]
    assert (inside, outside) == ("under the footing", "elsewhere") and 0 < under.sum() < under.size
    assert np.all(xz[under, 0] <= 0.05) and np.all(depth[under] <= 0.1)
    assert np.all((xz[~under, 0] > 0.05) | (depth[~under] > 0.1))


def test_an_unseen_combination_of_features_is_off_the_training_data():
    """Training states in two corners of the unit square: a state inside both features' ranges but
    in the empty corner is off the data (a per-feature box would pass it), one among them is not;
    of the training states themselves at most 1 % are off (the quantile of their leave-one-out
    distances; queried as they are, each counts itself among its neighbours)."""
    from granular_multiscale.analysis.problem_surrogate import NOVELTY_QUANTILE, TrainingStates

    rng = np.random.default_rng(0)
    train = np.concatenate([rng.uniform(0.0, 0.1, (500, 2)), rng.uniform(0.9, 1.0, (500, 2))])
    states = TrainingStates(train)
    assert states.off(np.array([0.05, 0.95])) and not states.off(np.array([0.05, 0.05]))
    assert 0 < states.off(train).mean() <= 1 - NOVELTY_QUANTILE + 1e-12
    np.testing.assert_array_equal(states.off(np.array([[[0.95, 0.05], [0.95, 0.95]]])), [[True, False]])


def plt_image_has_colour(path) -> bool:
    """The PNG was drawn: more than a few distinct colours."""
    import matplotlib.image as mpimg

    image = mpimg.imread(path)
    return len(np.unique(image.reshape(-1, image.shape[-1]), axis=0)) > 20


def test_quadratic_elements_do_not_lock_where_bilinear_ones_do(tmp_path):
    """The same softening biaxial test, 6 × 12 elements, a weak zone of 8 mm radius: quad8 (2 × 2
    points) localises into one band (ratio 5.91 measured to tiny.yaml's 7 %, at 45.5°), fully
    integrated quad4 locks under the band's isochoric flow (2.02)."""
    ratios = {}
    zone = {"center": [0.0125, 0.04], "radius": 0.008}
    for element in ("quad8", "quad4"):
        config = softening_config(tmp_path, biaxial={"elements": [6, 12], "element": element, "weak_zone": zone})
        ratios[element] = band_metrics(run_fem_reference(config, "biaxial", tmp_path / f"{element}.h5",
                                                         problem="biaxial"))["band_ratio"]
    assert ratios["quad8"] > 2.0 * ratios["quad4"], ratios


def test_a_step_without_equilibrium_stops_naming_it_and_keeps_the_converged_steps(tmp_path):
    """A brittle softening (k_s = 150 kPa over κs = 0.02) snaps back on the 3 × 6 mesh: no cutback
    finds equilibrium; the error names the load step and its axial strain, and the checkpoint
    keeps every converged step for a resume."""
    config = softening_config(tmp_path, biaxial={"elements": [3, 6]})
    config["elastoplastic"].update(softening=1.5e5, softening_strain=0.02)
    problem, path = problem_and_path(config, "biaxial", "biaxial")
    checkpoint = tmp_path / "run.ckpt"
    with pytest.raises(ConvergenceError, match=r"load step (\d+) \(axial strain [0-9.]+ -> [0-9.]+\) did not "
                                              r"converge after 6 cutbacks") as failure:
        problem.run(analytic_material("elastoplastic", problem, config), path, checkpoint=checkpoint,
                    progress=False)
    stopped = int(failure.value.partial.attrs["stopped_at_step"])
    assert failure.value.partial.sizes["step"] == stopped
    assert pickle.loads(checkpoint.read_bytes())["step"] == stopped - 1


# ------------------------------------------------------------------------ metrics
def test_band_metrics_find_a_band_of_known_inclination_and_width():
    """Gauss points on a grid of the x–z plane, shear strain 0.3 in a strip at 58° from the x axis,
    8 mm wide, 0.05 elsewhere; the minor principal stress along x: the metrics recover 58° and
    about 8 mm."""
    x, y = np.meshgrid(np.linspace(0.001, 0.049, 40), np.linspace(0.001, 0.099, 80))
    xy = np.column_stack([x.ravel(), y.ravel()])
    theta = np.radians(58.0)
    distance = (xy - [0.025, 0.05]) @ np.array([-np.sin(theta), np.cos(theta)])
    level = np.where(np.abs(distance) <= 0.004, 0.3, 0.05)
    steps = np.array([0.0, 0.5, 1.0])
    strain = np.zeros((3, len(xy), 6))
    strain[:, :, 0] = steps[:, None] * 0.5 * level  # isochoric pure shear: ε_s proportional to level
    strain[:, :, 2] = -steps[:, None] * 0.5 * level
    stress = np.tile([-P0, -1.5 * P0, -3 * P0, 0, 0, 0], (3, len(xy), 1))
    ds = xr.Dataset({"strain": (("step", "gp", "comp"), strain), "stress": (("step", "gp", "comp"), stress),
                     "gp_position": (("gp", "xyz"), np.column_stack([xy[:, 0], np.zeros(len(xy)), xy[:, 1]])),
                     "axial_strain": (("step",), [0.0, 0.05, 0.1])})
    m = band_metrics(ds)
    assert m["inclination_deg"] == pytest.approx(58.0, abs=1.0)
    assert m["width_m"] == pytest.approx(0.008, rel=0.25)
    expected_ratio = 0.3 / np.mean(level)
    assert m["band_ratio"] == pytest.approx(expected_ratio, rel=0.1)


def test_element_angles_of_a_known_response():
    """Plane strain with σ1 = 3 σ3 at the peak (sin φ = 0.5, φ = 30°) and strain increments of a
    dilatancy angle of 10°; and N_q(30°) = 18.40 (Prandtl–Reissner)."""
    n = 11
    s1 = np.r_[np.linspace(1.0, 3.0, 6), np.full(5, 2.5)] * P0
    stress = np.zeros((n, 1, 6))
    stress[:, 0, 2], stress[:, 0, 0], stress[:, 0, 1] = -s1, -P0, -1.5 * P0
    d1 = np.full(n - 1, 1e-3)
    sin_psi = np.sin(np.radians(10.0))
    d3 = -d1 * (1 + sin_psi) / (1 - sin_psi)  # −(d1 + d3)/(d1 − d3) = sin ψ
    strain = np.zeros((n, 1, 6))
    strain[1:, 0, 2] = -np.cumsum(d1)
    strain[1:, 0, 0] = -np.cumsum(d3)
    ds = xr.Dataset({"strain": (("step", "gp", "comp"), strain), "stress": (("step", "gp", "comp"), stress),
                     "axial_strain": (("step",), np.r_[0, np.cumsum(d1)])}, attrs={"problem": "biaxial"})
    a = element_angles(ds)
    assert a["peak_friction_deg"] == pytest.approx(30.0, abs=1e-9)
    assert a["dilatancy_at_peak_deg"] == pytest.approx(10.0, abs=1e-9)
    assert bearing_capacity_factor(30.0) == pytest.approx(18.401, abs=1e-3)


# ------------------------------------------------------------------------ bad input
def _config(**sections) -> dict:
    config = yaml.safe_load((ROOT / "config" / "tiny.yaml").read_text())
    config["problems"] = ["biaxial", "footing"]
    for name, values in sections.items():
        config[name] = {**config.get(name, {}), **values} if isinstance(values, dict) else values
    return config


@pytest.mark.parametrize("sections, key", [
    ({"problems": ["cavity"]}, "'problems[0]'"),
    ({"biaxial": {"weak_zone": {"center": [0.2, 0.05], "radius": 0.01}}}, "'biaxial.weak_zone'"),
    ({"biaxial": {"weak_zone": {"center": [0.0125, 0.04], "radius": 0.001}}}, "'biaxial.weak_zone'"),
    ({"footing": {"width": 1.2}}, "'footing.width'"),
    ({"footing": {"symmetry": "quarter"}}, "'footing.symmetry'"),
    ({"biaxial": {"load_paths": {"pull": {"segments": [[5, -0.01]]}}}}, "'biaxial.load_paths.pull.segments'"),
    ({"footing": {"load_paths": {"deep": {"segments": [[5, 1.5]]}}}}, "'footing.load_paths.deep.segments[0][1]'"),
    ({"biaxial": {"elements": [3, 3, 6]}}, "'biaxial.elements'"),
    ({"biaxial": {"element": "hex8"}}, "'biaxial.element'"),
    ({"footing": {"domain": [0.5, 0.3, 0.2]}}, "'footing.domain'"),
    ({"biaxial": {"uniform_field": True}}, "'biaxial.uniform_field'"),
])
def test_bad_problem_settings_name_the_key_and_write_nothing(tmp_path, sections, key):
    config = _config(output_dir=str(tmp_path / "out"), **sections)
    with pytest.raises((ConfigError, ProblemConfigError, ValueError)) as error:
        check_problems(validate_config(config))
    assert key in str(error.value), str(error.value)
    assert not (tmp_path / "out").exists()


def test_the_workflow_refuses_a_weak_zone_outside_the_mesh_before_any_rule_runs(tmp_path):
    """`snakemake -n all` stops at once with one line naming the key, and writes nothing."""
    out = tmp_path / "out"
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"output_dir": str(out), "biaxial": {"weak_zone": {"center": [0.2, 0.05],
                                                                                      "radius": 0.01}}}))
    result = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--configfile", "config/tiny.yaml", str(bad)],
                            cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode != 0
    assert "Configuration error: config key 'biaxial.weak_zone': center [0.2, 0.05] lies outside the specimen" \
        in result.stderr, result.stderr[-2000:]
    assert not out.exists()


def test_unknown_problem_and_path_are_named():
    config = validate_config(_config())
    with pytest.raises(ValueError, match="config key 'problems': unknown problem 'cavity'"):
        make_problem(config, "cavity")
    with pytest.raises(KeyError, match="'biaxial.load_paths' defines"):
        problem_and_path(config, "biaxial", "path2")


def test_the_weak_zone_gets_the_weak_packing():
    """DEM: the weak zone's points start from the weak packing (appended to the list); without one the
    run refuses to start, naming the key."""
    config = validate_config(_config())
    problem = make_problem(config, "biaxial")
    packings, assignment = dem_packings(problem, config, ["p0.gz"], "weak.gz")
    assert packings == ["p0.gz", "weak.gz"]
    assert np.array_equal(assignment, problem.zones()) and 0 < assignment.sum() < problem.n_gauss_points
    with pytest.raises(ValueError, match="'biaxial.weak_zone'"):
        dem_packings(problem, config, ["p0.gz"], None)


# ------------------------------------------------------------------------ real YADE
def dem_biaxial_config(tmp_path: Path) -> dict:
    """config/tiny.yaml's biaxial test (2 × 4 quad8, weak zone, to 7 %) with 100-sphere RVEs at the
    default scale's strain rate (5 /s; tiny.yaml's 2.5 is the rate of the triaxial tests' tolerances)."""
    return tiny_config(tmp_path / "o", {"path1": [[2, 0.002]]}, snapshot_interval=3, strain_rate=5.0)


@pytest.mark.needs_yade
@pytest.mark.slow
def test_biaxial_with_yade_rves_forms_a_band(tmp_path_factory, tmp_path):
    """32 RVEs of 100 spheres, two of them weak (frictionless): past the peak a band carries at
    least twice the specimen's mean shear strain.

    Why tiny.yaml's settings: a 100-sphere cell is a few of its largest grains wide. Inside a band
    at 9 % of the specimen's axial strain its side falls below two grain diameters (YADE stops:
    "Body larger than half of the cell size"), and its stress scatters from one trial to the next
    by a few per cent, so Newton at the default 2e-2 needs 20+ iterations a step past the peak.
    The frictionless weak zone localises earlier (measured at 2.5 /s: ratio 2.3 at 7 %, onset near 6 %;
    with μ 0.2 the ratio is 1.2 at 7 %), and 5e-2 matches the small RVE's scatter. At 5 /s
    Newton takes a few iterations a step past the peak; at 2.5 /s it stalled there on that scatter,
    at 2.5 times the cost (docs/history.md, "A CPU 2.6 times slower than the `all` record's")."""
    strong, _ = packing(tmp_path_factory)
    weak, _ = packing(tmp_path_factory, friction=0.0)
    from granular_multiscale.drivers.fem_dem import run_fem_dem

    config = dem_biaxial_config(tmp_path)
    assert config["biaxial"]["weak_zone"]["dem_friction"] == 0.0 and config["biaxial"]["dem_newton"]["tolerance"] == 0.05
    ds = run_fem_dem(config, "biaxial", [str(strong)], tmp_path / "b.h5", None, 2,
                     problem="biaxial", weak_packing=str(weak))
    m = band_metrics(ds)
    assert m["band_ratio"] >= 2.0, m
    assert 0.04 < m["onset_load"] < 0.07, m  # axial strain: past the peak, before the end
    assert ds.load_force.values[-1] < ds.load_force.max()  # softened past the peak
    assert ds.attrs["method"] == "dem" and ds.attrs["problem"] == "biaxial"


RUNNER = """
import pickle, sys
from granular_multiscale.drivers.fem_dem import run_fem_dem
from granular_multiscale.runlog import setup_logging
config, packings, weak, output, checkpoint = pickle.load(open(sys.argv[1], "rb"))
run_fem_dem(config, "p", packings, output, checkpoint, 2, logger=setup_logging(None), problem="biaxial",
            weak_packing=weak)
"""


def _start(tmp_path, args) -> subprocess.Popen:
    file = tmp_path / f"args_{time.monotonic_ns()}.pkl"
    file.write_bytes(pickle.dumps(args))
    return subprocess.Popen([sys.executable, "-c", RUNNER, str(file)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)


@pytest.mark.needs_yade
@pytest.mark.slow
def test_biaxial_fem_dem_resumes_after_kill_9_bit_for_bit(tmp_path_factory, tmp_path):
    strong, _ = packing(tmp_path_factory)
    weak, _ = packing(tmp_path_factory, friction=0.2)
    config = dem_biaxial_config(tmp_path)
    # loading, then the kill, then an unloading and a reloading step after the resume
    config["biaxial"]["load_paths"] = {"p": {"segments": [[2, 0.01], [1, 0.005], [1, 0.01]]}}
    from granular_multiscale.drivers.fem_dem import run_fem_dem

    whole = run_fem_dem(config, "p", [str(strong)], tmp_path / "whole.h5", None, 2, problem="biaxial",
                        weak_packing=str(weak))
    checkpoint = tmp_path / "ck" / "b.ckpt"
    args = (config, [str(strong)], str(weak), str(tmp_path / "b.h5"), str(checkpoint))
    proc = _start(tmp_path, args)
    deadline, step = time.time() + 600, -1
    while time.time() < deadline and proc.poll() is None:
        try:
            step = pickle.loads(checkpoint.read_bytes())["step"]
        except Exception:
            pass
        if step >= 2:
            os.killpg(proc.pid, signal.SIGKILL)
            break
        time.sleep(0.02)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL and 2 <= step < 4, proc.stderr.read()[-2000:]
    resumed = _start(tmp_path, args)
    _, err = resumed.communicate(timeout=600)
    assert resumed.returncode == 0, err[-3000:]
    assert f"resuming from checkpoint {checkpoint} after step {step}" in err
    again = read_run(tmp_path / "b.h5")
    for name in ("strain", "stress", "tangent", "displacement", "load_force", "newton_iterations", "particle_steps"):
        assert np.array_equal(whole[name].values, again[name].values), name


@pytest.mark.needs_yade
@pytest.mark.slow
def test_every_driver_runs_the_biaxial_test(tmp_path_factory, tmp_path):
    """FEM–ML and the adaptive set on the biaxial test: FEM–ML runs the path with the networks at
    every point (the weak zone's own at its points, when given), and the adaptive run with every point an anchor is FEM–DEM bit for bit (same
    problem, packings, weak zone and Newton settings)."""
    import torch

    from granular_multiscale.drivers.adaptive import run_adaptive
    from granular_multiscale.drivers.fem_dem import dem_newton_config, run_fem_dem
    from granular_multiscale.drivers.fem_ml import run_fem_ml
    from granular_multiscale.materials.elastoplastic import Elastoplastic
    from granular_multiscale.paths import load_paths_from_config
    from granular_multiscale.surrogate.dataset import build_dataset
    from granular_multiscale.surrogate.synthetic import material_point_run, triaxial_strain_paths
    from granular_multiscale.surrogate.training import train

    torch.set_num_threads(1)
    strong, _ = packing(tmp_path_factory)
    weak, _ = packing(tmp_path_factory, friction=0.2)
    config = dem_biaxial_config(tmp_path)
    config["biaxial"]["load_paths"] = {"p": {"segments": [[3, 0.006]]}}
    config["surrogate"].update(newton={}, ensemble_size=2, epochs=150, learning_rate=5e-3, batch_size=256)
    path = load_paths_from_config(config)["path1"]
    run = material_point_run(Elastoplastic.from_config(12, config), triaxial_strain_paths(path, 12, seed=2), path)
    sigma, _, _ = train(*build_dataset(run, 0.75, seed=0), "sigma", config["surrogate"], seed=0, config=config)
    sigma.save(tmp_path / "sigma.pt")

    ml = run_fem_ml(config, "p", tmp_path / "sigma.pt", None, "autodiff", progress=False, problem="biaxial")
    assert ml.attrs["problem"] == "biaxial" and ml.sizes == {**ml.sizes, "step": 4, "gp": 32}
    assert np.all(np.diff(ml.load_force.values) > 0)  # compression raises the platen force
    # networks of their own at the weak zone (here a copy of the specimen's, which these networks,
    # trained in seconds, keep Newton stable beside): the same run, the file recorded. To round-off,
    # not bit for bit: the two zones' batches are other matrix sizes, which some BLAS builds sum in
    # another order (measured: 1e-11 relative)
    shutil.copy(tmp_path / "sigma.pt", tmp_path / "weak_sigma.pt")
    zoned = run_fem_ml(config, "p", tmp_path / "sigma.pt", None, "autodiff", progress=False, problem="biaxial",
                       weak_zone_models={"sigma": tmp_path / "weak_sigma.pt", "tangent": None})
    assert zoned.attrs["surrogate_weak_zone_sigma_model"] == str(tmp_path / "weak_sigma.pt")
    for name in ("stress", "strain", "load_force", "stress_spread"):
        np.testing.assert_allclose(zoned[name].values, ml[name].values, rtol=1e-9,
                                   atol=1e-9 * np.abs(ml[name].values).max(), err_msg=name)

    packings = [str(strong)]
    dem = run_fem_dem(config, "p", packings, tmp_path / "dem.h5", None, 2, problem="biaxial", weak_packing=str(weak))
    every = {**config, "adaptive": {**config["adaptive"], "anchor_fraction": 1.0}}
    mixed = run_adaptive(every, "p", np.inf, packings, tmp_path / "sigma.pt", None, "autodiff", n_workers=2,
                         problem="biaxial", weak_packing=str(weak))
    for name in ("strain", "stress", "load_force", "newton_iterations"):
        assert np.array_equal(mixed[name].values, dem[name].values), name
    # the networks stand for one material: the weak zone's points run DEM from step 0, the others never
    # reach an infinite threshold. (These networks, trained in seconds, have indefinite tangents: beside
    # the stiffer DEM points Newton fails in step 1, which the run keeps as a partial run.)
    weak_zone = make_problem(config, "biaxial").zones() == 1
    local = run_adaptive(config, "p", np.inf, packings, tmp_path / "sigma.pt", None, "autodiff", n_workers=2,
                         problem="biaxial", weak_packing=str(weak), allow_partial=True)
    assert weak_zone.any() and local.attrs["adaptive_anchors"] == weak_zone.sum()
    assert np.array_equal(local.point_mode.values, np.broadcast_to(weak_zone, local.point_mode.shape))
    assert np.array_equal(local.stress.values[0, weak_zone], dem.stress.values[0, weak_zone])
    assert dem_newton_config(config, "biaxial")["newton"]["tolerance"] == 0.05  # tiny.yaml's
