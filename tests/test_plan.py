"""The workflow's plan without Snakemake: the output layout, the run sets, the labels, the rerun
triggers and what `all` asks for, at the tiny, default and paper scales."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from granular_multiscale.config import CONFIG_DIR, merged, read_config_file, validate_config
from granular_multiscale.plan import NETWORKS, TRAINING_KEYS, Layout, Plan, path_label

PLAN_SOURCE = Path(__file__).resolve().parents[1] / "workflow" / "granular_multiscale" / "plan.py"


def plan_of(*configs: str, **settings) -> Plan:
    """The plan of config files layered as Snakemake layers --configfile, and `settings` on top."""
    config = {}
    for name in configs:
        config = merged(config, read_config_file(CONFIG_DIR / name))
    return Plan(validate_config(merged(config, {"output_dir": "out", **settings})))


def test_layout_puts_every_kind_of_file_in_its_folder():
    L = Layout("out/")
    assert L.out == "out"
    assert L.run("fem_dem", "path2") == "out/fem_dem/path2.h5"
    assert L.fem_ml("{path}") == "out/fem_ml/{path}.h5"  # wildcards pass through
    assert L.model("sigma", "active/") == "out/active/models/nn_sigma.pt"
    assert L.dataset("heldout") == "out/dataset/heldout.h5"
    assert L.training("sigma_mae.csv", "active/") == "out/active/training/sigma_mae.csv"
    assert L.adaptive("t0.02", "path2") == "out/adaptive/t0.02/path2.h5"
    assert L.adaptive_dem_points("t0.01", "path2", "active/") == "out/active/adaptive/t0.01/dem_points/path2.h5"
    assert L.packings(2, spheres=100) == ["out/rve_n100/packing_0.yade.gz", "out/rve_n100/packing_1.yade.gz"]
    assert L.packing_summary() == "out/rve/summary.json"
    assert L.log("fem_dem/path1") == "out/logs/fem_dem/path1.log"
    assert L.benchmark("surrogate/train_sigma") == "out/benchmarks/surrogate/train_sigma.tsv"
    assert L.checkpoint("adaptive/t0.02/path2") == "out/checkpoints/adaptive/t0.02/path2.ckpt"
    assert L.problem_run("biaxial", "fem_dem", "biaxial") == "out/biaxial/fem_dem/biaxial.h5"
    assert L.vtk("fem_ml", "path2") == "out/vtk/fem_ml/path2"


def test_a_bench_record_goes_under_the_output_dir():
    assert Layout("out/").bench("fem_ml") == "out/bench/fem_ml.json"
    assert plan_of("tiny.yaml", output_dir="results/tiny").layout.bench("dem") == "results/tiny/bench/dem.json"


def test_the_default_scale_trains_on_path1_and_rve_paths_and_validates_on_path2():
    plan = plan_of("config.yaml")
    assert plan.reference == "fem_dem" and plan.path_names == ["path1", "path2"]
    assert plan.training_run_paths == ["path1"] and plan.training_rve_sets == ["designed", "long", "band", "pressure"]
    assert plan.validation_paths == ["path2"] and plan.ml_paths == ["path2", "path1"]
    sources, networks = plan.training_rounds()[""]
    assert sources == ["out/fem_dem/path1.h5", "out/rve_paths/designed.h5", "out/rve_paths/long.h5",
                       "out/rve_paths/band.h5", "out/rve_paths/pressure.h5"]
    # the default tangent is NNσ's autodiff Jacobian: FEM–ML and its no-history ablation read no ND,
    # and ND's training is no part of making the surrogate they use
    assert list(networks) == ["sigma", "tangent", "sigma_nohist"]
    assert plan.fem_ml_models() == {"sigma": "out/models/nn_sigma.pt"}
    assert plan.fem_ml_models(history=False) == {"sigma": "out/models/nn_sigma_nohist.pt"}
    trainings = [item for item, _, _ in plan.surrogate_cost_items() if item.startswith("training")]
    assert trainings == ["training NNσ (rule train_sigma)"]
    assert list(plan.training_curves()) == ["NNσ|with history", "ND|with history", "NNσ|no history"]
    # the paper's tangent, ND: the ablation is solved with its own ND, which is then trained too
    nn = plan_of("config.yaml", surrogate={"tangent": "nn"})
    assert nn.training_rounds()[""][1] == NETWORKS and "out/models/nn_tangent_nohist.pt" in nn.all_targets()
    assert nn.fem_ml_models(history=False) == {"sigma": "out/models/nn_sigma_nohist.pt",
                                               "tangent": "out/models/nn_tangent_nohist.pt"}
    assert nn.fem_ml_models() == {"sigma": "out/models/nn_sigma.pt", "tangent": "out/models/nn_tangent.pt"}
    assert [item for item, _, _ in nn.surrogate_cost_items() if item.startswith("training")] == [
        "training NNσ (rule train_sigma)", "training ND (rule train_tangent)"]
    assert "out/models/nn_tangent_nohist.pt" not in plan.all_targets()
    active_sources, active_networks = plan.training_rounds()["active/"]
    assert active_sources[:-1] == sources and active_sources[-1:] == ["out/adaptive/t0.01/dem_points/path2.h5"]
    assert list(active_networks) == ["sigma", "tangent"]
    # the weak zone's networks: the sets band_weak and band_weak_cycles drive the weak packing;
    # FEM–ML's biaxial test reads them
    weak_sources, weak_networks = plan.training_rounds()["weak_zone/"]
    assert weak_sources == ["out/rve_paths/band_weak.h5", "out/rve_paths/band_weak_cycles.h5"]
    assert list(weak_networks) == ["sigma", "tangent"]
    for weak_set in ("band_weak", "band_weak_cycles"):
        assert plan.rve_path_packings(weak_set) == ["out/rve/packing_weak.yade.gz"]
    assert plan.rve_path_packings("band") == plan.packings
    assert plan.weak_zone_models("biaxial") == {"weak_sigma": "out/weak_zone/models/nn_sigma.pt",
                                                "weak_tangent": "out/weak_zone/models/nn_tangent.pt"}
    assert plan.weak_zone_models("footing") == {}
    # a problem's FEM–ML run reads the weak zone's NNσ too, and its ND only when solved with ND
    assert plan.fem_ml_models(problem="biaxial") == {"sigma": "out/models/nn_sigma.pt",
                                                     "weak_sigma": "out/weak_zone/models/nn_sigma.pt"}
    assert plan.fem_ml_models(problem="biaxial", tangent="nn") == {
        "sigma": "out/models/nn_sigma.pt", "tangent": "out/models/nn_tangent.pt", **plan.weak_zone_models("biaxial")}
    assert plan.fem_ml_models(problem="footing") == {"sigma": "out/models/nn_sigma.pt"}
    # the spread's scale: each network pair FEM–ML uses, on its own held-out trajectories
    assert plan.spread_scale_inputs() == {
        "specimen_sigma": "out/models/nn_sigma.pt", "specimen_heldout": "out/dataset/heldout.h5",
        "weak_zone_sigma": "out/weak_zone/models/nn_sigma.pt", "weak_zone_heldout": "out/weak_zone/dataset/heldout.h5"}
    assert plan.validation_cases() == {"path2": "validation path", "path1": "training path"}


def test_labels_and_run_sets_of_the_products():
    plan = plan_of("config.yaml")
    assert list(plan.comparison_runs("path2").items()) == [
        ("FEM–DEM (400 spheres)", "out/fem_dem/path2.h5"), ("FEM–ML (autodiff tangent)", "out/fem_ml/path2.h5"),
        ("FEM–ML, no history", "out/fem_ml_nohist/path2.h5")]
    timing = plan.timing_runs("path2")
    assert timing["FEM–ML (nn tangent)"] == "out/fem_ml_nn/path2.h5"
    assert timing["FEM–DEM (100 spheres)"] == "out/fem_dem_n100/path2.h5"
    # adaptive.report: the adaptive runs join, from the highest threshold to the lowest, then their controls
    adaptive = ["adaptive FEM–DEM–ML, threshold 0.02", "adaptive FEM–DEM–ML, threshold 0.01"]
    assert list(timing)[-4:] == [*adaptive, *plan.control_runs("path2")]
    assert plan.control_runs("path2") == {
        "control: elastoplastic model fitted to Path1 + the DEM points of threshold 0.02": "out/adaptive/t0.02_elastoplastic/path2.h5",
        "control: elastoplastic model fitted to Path1 + the DEM points of threshold 0.01": "out/adaptive/t0.01_elastoplastic/path2.h5"}
    assert plan.speed_curve("path2") == ["FEM–ML (autodiff tangent)", *adaptive, "FEM–DEM (400 spheres)"]
    assert plan.adaptive_run_files() == ["out/adaptive/t0.02/path2.h5", "out/adaptive/t0.01/path2.h5"]
    elastoplastic = plan_of("config.yaml", reference_material="elastoplastic")
    assert elastoplastic.reference_run("path2") == "out/fem_elastoplastic/path2.h5"
    assert elastoplastic.speed_curve("path2") == []  # adaptive runs need DEM
    assert "FEM–DEM (100 spheres)" not in elastoplastic.timing_runs("path2")
    assert path_label("path2") == "Path2"


def test_the_surrogate_on_the_problems_beside_its_controls():
    """Default scale: per problem the reference, FEM–ML, FEM–ML solved as the reference is, its networks
    along the reference's strains, the analytic model alone, the adaptive run (biaxial: no promotions, DEM at the weak zone only;
    footing: promoted by the distance to the training data) and its control, and the products of
    each; the tiny scale (no adaptive report) keeps the runs without DEM."""
    plan = plan_of("config.yaml")
    assert list(plan.problem_comparison("biaxial", "biaxial").items()) == [
        ("FEM–DEM (400 spheres)", "out/biaxial/fem_dem/biaxial.h5"),
        ("FEM–ML (autodiff tangent)", "out/biaxial/fem_ml/biaxial.h5"),
        ("FEM–ML solved as the reference (its Newton settings, ND tangent)", "out/biaxial/fem_ml_as_reference/biaxial.h5"),
        ("FEM–ML's networks along the reference's strains (no FEM)", "out/biaxial/fem_ml_driven/biaxial.h5"),
        ("FEM, elastoplastic model fitted to Path1 (no networks)", "out/biaxial/fem_elastoplastic/biaxial.h5"),
        ("adaptive FEM–DEM–ML, no promotions (DEM at the anchors)", "out/biaxial/adaptive/biaxial.h5"),
        ("control: elastoplastic model fitted to Path1 + the same DEM points",
         "out/biaxial/control_elastoplastic/biaxial.h5")]
    assert plan.problem_threshold("biaxial") == np.inf and plan.problem_threshold("footing") == 0.6
    # the biaxial test's adaptive run gives its networks ND's tangent (solved as FEM–DEM is); the others surrogate.tangent
    assert (plan.adaptive_tangent("biaxial"), plan.adaptive_tangent("footing"), plan.adaptive_tangent()) == \
        ("nn", "autodiff", "autodiff")
    assert plan.problem_surrogate_definition("biaxial", adaptive=True)["adaptive"]["tangent"] == "nn"
    assert list(plan.problem_adaptive_runs("footing", "footing"))[0] == "adaptive FEM–DEM–ML, distance ≥ 0.6"
    assert plan.layout.problem_dem_points("footing", plan.problem_adaptive_method, "footing") == \
        "out/footing/adaptive/dem_points/footing.h5"
    # the footing's adaptive run depends on its own settings over the adaptive section; the biaxial's does not
    footing, biaxial = (plan.problem_surrogate_definition(p, adaptive=True) for p in ("footing", "biaxial"))
    assert footing["adaptive"]["indicator"] == "distance" and biaxial["adaptive"]["indicator"] == "spread"
    assert "threshold" not in footing["adaptive"] and footing["threshold"] == 0.6 and "adaptive" not in footing["section"]
    targets = plan.all_targets()
    assert {"out/tables/biaxial/surrogate_biaxial.csv", "out/tables/footing/surrogate_footing.csv",
            "out/tables/visited_states.csv"} <= set(targets)
    states = plan.visited_states_runs()
    assert list(states.values()) == ["out/fem_dem/path1.h5", "out/rve_paths/designed.h5", "out/rve_paths/long.h5",
                                     "out/rve_paths/band.h5", "out/rve_paths/pressure.h5", "out/fem_dem/path2.h5",
                                     "out/biaxial/fem_dem/biaxial.h5", "out/footing/fem_dem/footing.h5"]
    # what an adaptive problem run depends on: the DEM settings and the adaptive section, not the thresholds of Path2
    assert plan.problem_surrogate_definition("biaxial", adaptive=True)["dem"] == plan.run_definition
    other = plan_of("config.yaml", adaptive={"report": True, "problems": True, "thresholds": [0.5]})
    assert other.problem_surrogate_definition("biaxial", True) == plan.problem_surrogate_definition("biaxial", True)
    assert "dem" not in plan.problem_surrogate_definition("biaxial")  # FEM–ML runs no DEM
    # the default `all` runs the problems' adaptive runs beside FEM–ML; without adaptive.problems
    # they are target problem_adaptive_runs
    assert plan.problem_adaptive
    off = plan_of("config.yaml", adaptive={"report": True, "problems": False}, biaxial={"adaptive": {"threshold": 0.02}})
    assert not off.problem_adaptive and len(off.problem_comparison("biaxial", "biaxial")) == 5
    assert list(off.problem_adaptive_runs("biaxial", "biaxial").items()) == [
        ("adaptive FEM–DEM–ML, threshold 0.02", "out/biaxial/adaptive/biaxial.h5"),
        ("control: elastoplastic model fitted to Path1 + the same DEM points", "out/biaxial/control_elastoplastic/biaxial.h5")]
    assert off.problem_threshold("biaxial") == 0.02
    both = plan_of("config.yaml", adaptive={"report": True, "problems": True,
                                            "controls": ["linear_elastic", "elastoplastic"]})
    assert list(both.problem_comparison("footing", "footing"))[-2:] == [
        "control: elastic model + the same DEM points", "control: elastoplastic model fitted to Path1 + the same DEM points"]
    tiny = plan_of("config.yaml", "tiny.yaml")
    assert list(tiny.problem_comparison("footing", "footing").values()) == [
        "out/footing/fem_dem/footing.h5", "out/footing/fem_ml/footing.h5", "out/footing/fem_ml_as_reference/footing.h5",
        "out/footing/fem_ml_driven/footing.h5", "out/footing/fem_elastoplastic/footing.h5"]
    elastoplastic = plan_of("config.yaml", reference_material="elastoplastic")
    assert list(elastoplastic.problem_comparison("biaxial", "biaxial").values()) == [
        "out/biaxial/fem_elastoplastic/biaxial.h5", "out/biaxial/fem_ml/biaxial.h5",
        "out/biaxial/fem_ml_as_reference/biaxial.h5", "out/biaxial/fem_ml_driven/biaxial.h5"]


def test_rerun_triggers_hold_what_changes_a_result_and_nothing_else():
    plan = plan_of("config.yaml")
    other_host = plan_of("config.yaml", dem={"executor": "dask", "n_workers": 7})
    assert plan.run_definition == other_host.run_definition  # where DEM runs is not what it computes
    assert "newton" in plan.run_definition and "newton" not in plan.packing_definition
    assert set(plan.training_settings()) == set(TRAINING_KEYS)
    segments = plan.fem_ml_definition("path2")["segments"]
    assert segments == plan.config["load_paths"]["path2"]["segments"]
    assert plan.adaptive_definition("path2")["dem"] == plan.run_definition
    variant, settings = next(iter(plan.config["tolerance_study"]["variants"].items()))
    assert plan.study_dem(variant)["newton"] == {**plan.config["dem"]["newton"], **settings}
    # a problem's adaptive settings are its adaptive run's alone: its reference and FEM–ML runs stay
    other_adaptive = plan_of("config.yaml", biaxial={"adaptive": {"threshold": 0.02}})
    assert other_adaptive.problem_definition("biaxial") == plan.problem_definition("biaxial")
    assert other_adaptive.problem_surrogate_definition("biaxial") == plan.problem_surrogate_definition("biaxial")
    assert other_adaptive.problem_surrogate_definition("biaxial", adaptive=True) != \
        plan.problem_surrogate_definition("biaxial", adaptive=True)


@pytest.mark.parametrize("configs", [("config.yaml",), ("config.yaml", "tiny.yaml"), ("config.yaml", "paper.yaml")])
def test_all_asks_for_the_products_of_every_stage_once(configs):
    plan = plan_of(*configs)
    targets = plan.all_targets()
    assert len(targets) == len(set(targets)) and all(t.startswith("out/") for t in targets)
    L = plan.layout
    assert {plan.reference_run(p) for p in plan.path_names} <= set(targets)
    assert {L.fem_ml(p) for p in plan.ml_paths} | {L.model(n) for n in plan.networks} <= set(targets)
    # the paper's scale solves with ND (surrogate.tangent: nn): all four networks
    assert (plan.networks == NETWORKS) == ("paper.yaml" in configs)
    assert {L.table("headline.json"), L.figure("speed_vs_error.png"), L.table("validation_by_phase.csv")} <= set(targets)
    assert (L.figure("adaptive_mode_map.png") in targets) == plan.adaptive_in_report
    for problem in plan.problems:
        assert L.figure(f"{problem}/response.png") in targets
        assert {L.vtk(problem, case) for case in plan.problem_cases[problem]} <= set(targets)
    assert (L.table("biaxial_bands.csv") in targets) == ("biaxial" in plan.problems)


def test_the_biaxial_mesh_study_reuses_the_configured_mesh():
    plan = plan_of("config.yaml")
    configured = "x".join(map(str, plan.config["biaxial"]["elements"]))
    first_case = list(plan.config["biaxial"]["load_paths"])[0]
    assert plan.biaxial_mesh_run(configured) == plan.problem_run("biaxial", first_case)
    assert plan.biaxial_mesh_run("1x2") == "out/biaxial_mesh/fem_dem/1x2.h5"
    assert plan.weak_packing_input("footing") == []


def test_the_plan_imports_no_snakemake_and_opens_no_file():
    tree = ast.parse(PLAN_SOURCE.read_text())
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not any(m.startswith("snakemake") for m in imported)
    calls = {n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
    assert "open" not in calls


def test_the_reference_newton_settings_are_those_the_fem_dem_runs_solve_with():
    from granular_multiscale.drivers.fem_dem import dem_newton_config

    for plan in (plan_of("config.yaml"), plan_of("config.yaml", dem={"newton": {"tolerance": 5e-4}})):
        solved = dem_newton_config(plan.config)["newton"]
        assert plan.reference_newton == {key: solved[key] for key in ("tolerance", "predictor", "acceleration")}
    assert plan.reference_newton["tolerance"] == 5e-4


def test_a_study_variant_solved_like_the_reference_is_the_reference_run():
    """The default study's tol2e-3 is dem.newton's own setting: the study reads fem_dem/path2.h5
    rather than computing it again; with dem.newton at 5e-4 it is a run of its own again."""
    plan = plan_of("config.yaml")
    runs = {v: plan.study_run(v) for v in plan.config["tolerance_study"]["variants"]}
    assert runs.pop("tol2e-3") == "out/fem_dem/path2.h5"
    assert runs == {v: f"out/tolerance_study/{v}/path2.h5" for v in runs}
    stricter = plan_of("config.yaml", dem={"newton": {"tolerance": 5e-4}})
    assert stricter.study_run("tol2e-3") == "out/tolerance_study/tol2e-3/path2.h5"
    # the settings compared are those the run solves with: a variant's unnamed keys take the
    # schema's defaults (max_iterations 40), not dem.newton's (30)
    study = {"variants": {"a": {"tolerance": 2e-3, "predictor": "extrapolate", "max_iterations": 30},
                          "b": {"tolerance": 2e-3}}, "converged": "a", "baseline": "b"}
    plan = plan_of("config.yaml", tolerance_study=study)
    assert plan.study_run("a") == "out/fem_dem/path2.h5"
    assert plan.study_run("b") == "out/tolerance_study/b/path2.h5"


@pytest.mark.parametrize("scale", ["config.yaml", "tiny.yaml"])
@pytest.mark.parametrize("test", ["triaxial", "biaxial"])
def test_the_element_tests_configs_validate_as_their_rule_validates_them(scale, test):
    """Pass criterion: a rule's script validates the config with its overrides (an element test's:
    one RVE, a uniform field, no weak zone), so those overrides must make a valid config at every
    scale; the weak zone's networks are then simply unused."""
    plan = plan_of(*(["config.yaml"] if scale == "config.yaml" else ["config.yaml", scale]))
    config = validate_config({**plan.config, **plan.element_test_overrides(test)})
    if test == "biaxial":
        assert Plan(config).weak_zone_models("biaxial") == {}
        assert list(Plan(config).spread_scale_inputs()) == ["specimen_sigma", "specimen_heldout"]
