"""The workflow at the tiny scale, on the elastoplastic reference and on FEM–DEM with real
YADE RVEs, then the HTML report: Snakemake must build every figure and table from scratch, and
`snakemake --report` must put each of them, with its caption, the headline page among them, into
one self-contained file. A FEM–ML run that stops early (it may on the tiny scale's noisy 150-sphere
DEM data) must still reach the report, labelled as such."""

import base64
import html as html_module
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from PIL import Image

import figure_checks as check
from dem_fixtures import ROOT
from granular_multiscale.data import read_run
from granular_multiscale.plan import FIELD_QUANTITIES, path_label
from tiny_chain import FIGURES, TABLES, TinyChain, problem_products, snakemake


def plain(html_text):
    """The text of an HTML fragment, whitespace collapsed."""
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", "", html_text))


def report_item(results, name):
    """The text of the file ``name`` embedded in a report (``results``: the report's own index)."""
    [entry] = [entry for entry in results.values() if entry["name"] == name]
    return base64.b64decode(entry["data_uri"].split(",", 1)[1]).decode()


def page_text(page):
    """The text of an HTML page's body, as a reader sees it."""
    return html_module.unescape(plain(page.split("<body>", 1)[1]))


def check_figures(plan, again: Path) -> None:
    """Each figure the workflow drew shows the data of the files it was drawn from: its function,
    called again here on those files (the rule's arguments, from the plan), draws the same pixels,
    and what it drew is what figure_checks computes from the run files, the dataset's split and
    the tables."""
    from granular_multiscale.analysis import calibration, products

    L, settings, path = plan.layout, plan.config["analysis"], plan.validation_path
    files = plan.comparison_runs(path)
    runs = {label: read_run(f) for label, f in files.items()}
    ref, ml = plan.reference_label, plan.surrogate_label
    labels = {"path_label": path_label(path), "reference_label": ref, "surrogate_label": ml}
    split = (L.dataset("train"), L.dataset("heldout"))
    with xr.open_dataset(split[0], engine="h5netcdf") as train, xr.open_dataset(split[1], engine="h5netcdf") as heldout:
        train_gp = np.asarray(train.attrs["train_gp"]).ravel()
        heldout_gp = np.asarray(heldout.attrs["heldout_gp"]).ravel()

    def same(name, kind, rows=1):
        """The workflow's PNG has the size the settings ask for and the pixels of the one drawn again."""
        check.check_png(L.figure(name), products._size(settings, kind, rows=rows), products._dpi(settings))
        with Image.open(L.figure(name)) as theirs, Image.open(again / name) as ours:
            assert np.array_equal(np.asarray(theirs.convert("RGB")), np.asarray(ours.convert("RGB"))), name

    drawn = products.make_error_map(files[ref], files[ml], *split, again / "error_map.png", settings, **labels)
    same("error_map.png", "error_map")
    check.check_error_map(drawn, runs[ref], runs[ml], train_gp, heldout_gp)

    names = plan.stress_strain_names()
    chosen, drawn = products.make_stress_strain(files, *split, {n: again / f"stress_strain_{n}.png" for n in names},
                                                settings, path_label=labels["path_label"])
    for name in names:
        same(f"stress_strain_{name}.png", "line")
        check.check_stress_strain(drawn[name], runs, chosen[name])

    drawn = products.make_global_response(files, again / "top_force_volumetric_strain.png", settings,
                                          path_label=labels["path_label"])
    same("top_force_volumetric_strain.png", "line")
    check.check_global_response(drawn, runs)

    n_steps = runs[ref].sizes["step"]
    steps = [s if s >= 0 else n_steps + s for s in settings["field_steps"]]
    for quantity in FIELD_QUANTITIES:
        drawn = products.make_field_figure(files[ref], files[ml], quantity, again / f"fields_{quantity}.png", settings,
                                           **labels)
        same(f"fields_{quantity}.png", "field_row", rows=len(steps))
        check.check_fields(drawn, runs[ref], runs[ml], quantity, steps)

    curves = plan.training_curves()
    drawn = products.make_training_curves(curves, again / "training_curves.png", settings)
    same("training_curves.png", "line")
    check.check_training_curves(drawn, curves)

    speedup, accuracy = L.table("speedup.csv"), L.table("accuracy.csv")
    drawn = products.make_speed_vs_error(speedup, accuracy, again / "speed_vs_error.png", settings,
                                         curve=plan.speed_curve(path))
    same("speed_vs_error.png", "speed")
    check.check_speed_vs_error(drawn, speedup, accuracy)

    _, drawn = calibration.make_calibration(files[ml], files[ref], again / "calibration.png", again / "calibration.csv",
                                            again / "calibration.html", settings, **labels,
                                            spread_scales=calibration.read_spread_scales(L.table("spread_scale.csv")))
    same("calibration.png", "line")
    check.check_calibration(drawn, runs[ml], runs[ref])


@pytest.mark.slow
@pytest.mark.parametrize("reference", ["elastoplastic", pytest.param("dem", marks=pytest.mark.needs_yade)])
def test_tiny_pipeline_builds_the_report(request, tmp_path, reference):
    """The elastoplastic chain builds its report in the same call (--report-after-run, in the
    session's fixture, tests/conftest.py), the DEM chain with a second call (--report), with the
    tolerance study's page of the reference's own error. Either way a dry run afterwards has
    nothing to do."""
    from granular_multiscale.analysis import tables

    if reference == "elastoplastic":  # with the problems beyond the triaxial specimen, as `all` makes them
        chain = request.getfixturevalue("tiny_elastoplastic_chain")
    else:  # training epochs as config/tiny.yaml sets them
        chain = TinyChain.at(
            tmp_path, reference,
            problems=[],  # (the problems with YADE RVEs: tests/test_problems.py)
            dem={"strain_rate": 5.0},  # the default scale's rate: half the DEM steps of tiny.yaml's 2.5
            # the reference's own error in "0 Headline": a two-variant tolerance study
            tolerance_study={"converged": "tight", "baseline": "default", "variants": {
                "default": {"tolerance": 2.0e-3, "max_iterations": 30}, "tight": {"tolerance": 5.0e-4}}})
        snakemake("-j2", *chain.config_args, "--", *chain.targets, "tolerance_study")
        snakemake("--report", str(chain.report), *chain.config_args, "--", "all", "tolerance_study")
    plan, report = chain.plan, chain.report
    L = plan.layout
    problem_items, _ = problem_products(L)
    again = snakemake("-n", "-j2", *chain.config_args, "--", *chain.targets)
    assert "Nothing to be done" in again.stdout + again.stderr, (again.stdout + again.stderr)[-3000:]
    check_figures(plan, tmp_path / "again")
    for name in TABLES:  # every table has rows of finite numbers
        path = Path(L.table(name))
        if path.suffix == ".html":
            assert path.read_text().count("<td") >= 2, name
            continue
        table = pd.read_csv(path)
        # NaN may mark what a tiny run leaves undefined (a ratio to an ensemble spread of zero),
        # never a whole table, and nothing is infinite
        numbers = table.select_dtypes("number")
        assert len(table) > 0 and numbers.notna().sum().sum() > 0.5 * numbers.size, name
        assert not np.isinf(numbers.to_numpy(dtype=float)).any(), name

    reference_run = read_run(plan.reference_run("path2"))
    fem_ml = read_run(L.fem_ml("path2"))
    n_ref, n_ml = reference_run.sizes["step"], fem_ml.sizes["step"]
    assert n_ref == 58  # step 0 and the 57 load steps of path2
    # a FEM–ML run that stops fails its rule (surrogate.keep_partial_runs is false): this one went to the end
    assert fem_ml.attrs["completed"] == 1 and n_ml == n_ref and "stopped_at_step" not in fem_ml.attrs
    vtk = Path(L.vtk("fem_ml", "path2"))
    assert (vtk / "path2.pvd").is_file() and len(list(vtk.glob("path2_*.vtu"))) == n_ml

    html = report.read_text()
    for name in FIGURES + TABLES:
        assert f'"name": "{name}"' in html, f"{name} missing from the report"
    # the PNGs are embedded, not linked: each figure's bytes are in the page
    embedded = set(re.findall(r"data:image/png;[^,\"]*base64,([A-Za-z0-9+/=]+)", html))
    for name in FIGURES:
        assert base64.b64encode(Path(L.figure(name)).read_bytes()).decode() in embedded, name
    # every result has its caption, every category shows up
    results = json.loads(re.search(r"var results = (\{.*?\});\n", html).group(1))
    for path, entry in results.items():
        assert "What to look for" in entry["caption"] or Path(path).suffix == ".csv", path
    for category in ("0 Headline", "1 Gauss points", "2 Specimen", "3 Speed and accuracy", "4 Training",
                     "6 Uncertainty"):
        assert category in html
    # the front page states scale and reference material (from the config) and points to the
    # headline page, which states what ran, the reference's tolerance, the machine and the numbers
    headline = json.loads(Path(L.table("headline.json")).read_text())
    display = headline["display"]
    raw = json.loads(re.search(r"var workflow_desc = (\".*?\");\n", html).group(1))
    assert "System Message" not in raw  # reStructuredText rendered without errors
    description = plain(raw)
    assert "category 0 Headline, a page the run writes with tables/headline.json" in description
    assert "Speedup" not in description and "Measured on" not in description  # no number of the run
    page = report_item(results, "headline.html")
    assert page == Path(L.table("headline.html")).read_text()
    page = page_text(page)
    if reference == "elastoplastic":
        assert "Analytic elastoplastic model" in description and "not FEM–DEM" in description
        # the problems: named on the front page, each product in its category with its caption
        assert "plane-strain biaxial test: 50 × 100 mm, 2 × 4 quad8 elements, 32 Gauss points (RVEs)" in description
        assert "strip footing: width 100 mm, half of a domain" in description
        assert "7 Problems beyond the triaxial specimen" in html and "8 The surrogate on the problems" in html
        for p in ("biaxial", "footing"):  # FEM–ML on the problems, against the reference, to the end
            surrogate = pd.read_csv(L.table(f"{p}/surrogate_{p}.csv"))
            # the reference, FEM–ML, FEM–ML solved as the reference, its networks along the reference's strains
            assert len(surrogate) == 4 and surrogate["force: largest error (% of peak)"].iloc[0] == 0
            assert np.isfinite(surrogate["force: largest error (% of peak)"].iloc[1:]).all()
            # along the reference's strains: the reference's kinematics, the networks' own force
            assert surrogate["volumetric strain: largest error (% of its peak)"].iloc[3] == 0
        for name in problem_items:
            assert f'"name": "{Path(name).name}"' in html, f"{name} missing from the report"
        bands = pd.read_csv(L.table("biaxial_bands.csv"))
        assert list(bands["mesh"]) == ["2x4"] and bands["Gauss points"].iloc[0] == 32
        assert (Path(L.vtk("biaxial", "biaxial")) / "biaxial_biaxial.pvd").is_file()
        assert len(list(Path(L.vtk("biaxial", "biaxial")).glob("*.vtu"))) == 15  # step 0 and 14 load steps
    else:
        assert "YADE RVEs of 150 spheres" in description and "Analytic" not in description
        assert Path(plan.reference_run("path1")).is_file() and Path(L.packing_summary()).is_file()
    assert headline["surrogate_completed"] is True
    assert headline["surrogate_load_steps"] == n_ml - 1 and headline["reference_load_steps"] == n_ref - 1
    assert "stopped after load step" not in page

    # what ran: the full 1×1×2 mesh, one material point per Gauss point
    speed = pd.read_csv(L.table("speedup.csv"))
    this = speed[speed["source"] == "this run"].set_index("method")
    assert (this["rves"] == 16).all()
    assert headline["gauss_points"] == headline["gauss_points_modelled"] == headline["material_points_evaluated"] == 16
    assert headline["symmetry"] == "none" and headline["uniform_field"] is False
    assert "the full specimen, 16 Gauss points (no symmetry reduction)" in page
    points = "RVEs" if reference == "dem" else "material points"
    assert f"the reference evaluated 16 {points}, one per Gauss point" in page
    assert f"Measured on {headline['machine']['cores']} cores of {headline['machine']['cpu']}" in page
    assert (f"Speedup {display['speedup']} for one answer: {headline['surrogate']} took {display['surrogate_wall_time']}, "
            f"{headline['reference']} {display['reference_wall_time']}") in page
    assert f"Top-force error {display['top_force_max_rel_pct']} of the peak" in page
    assert f"Held-out stress MAE {display['stress_mae_heldout_kpa']}" in page
    assert (f"Without history variables ({headline['ablation']}): top-force error "
            f"{display['ablation_top_force_max_rel_pct']}, held-out stress MAE "
            f"{display['ablation_stress_mae_heldout_kpa']}") in page
    assert "e+0" not in page and "e-0" not in page and "n/a" not in page  # no exponent notation, no gap

    # the reference's tolerance, the residual it reached and (DEM: from the study) its own error
    newton = headline["reference_newton"]
    assert newton["tolerance"] == reference_run.attrs["newton_tolerance"]
    assert newton["residual_relative_max"] == pytest.approx(reference_run.residual_relative.values.max())
    assert f"The reference was solved to a relative residual of {display['reference_tolerance']} " in page
    assert display["reference_tolerance"] == ("0.002" if reference == "dem" else "0.00000001")
    if reference == "dem":  # in the page tolerance_study wrote, beside the headline page
        assert (newton["tolerance"], newton["predictor"], newton["acceleration"]) == (2e-3, "extrapolate", "anderson")
        assert "Its own error is measured by the tolerance study" in page
        assert "The reference's own error, from the tolerance study: the page Reference convergence there" in description
        study = pd.read_csv(L.table("tolerance_study.csv")).set_index("variant")
        own = page_text(report_item(results, "reference_convergence.html"))
        assert "solved to a relative residual of 0.002 (extrapolate predictor, Anderson mixing;" in own
        assert f"top force within {study.loc['default', 'top_force_max_pct']:.2f} % of the peak" in own
        assert f"volumetric strain within {study.loc['default', 'volumetric_strain_max_pct']:.2f} %" in own
        assert "variant default against a run to 0.0005" in own
        assert "tolerance_study.png" in html and "5 Reference" in html
        # the variant solved like the reference is the reference run, not a second one
        assert not Path(L.tolerance_run("default", "path2")).exists() and Path(L.tolerance_run("tight", "path2")).exists()
    else:
        assert "Its own error is not measured by this workflow" in page
        assert not any(entry["name"] == "reference_convergence.html" for entry in results.values())

    # the full cost of an answer: every item as its file says, their total, the break-even
    cost = pd.read_csv(L.table("surrogate_cost.csv"))
    items = cost[cost["kind"] == "surrogate cost"].set_index("item")["wall_time_s"]
    training_run = read_run(plan.reference_run("path1"))
    expected = {"reference run of Path1": tables.run_wall_time(training_run)}
    if reference == "dem":
        expected["RVE preparation"] = tables.rve_preparation_seconds(L.packing_summary())
    # the RVE paths are a training source (config/tiny.yaml): their rule's wall time counts too
    expected["RVE paths 'designed'"] = tables.benchmark_seconds(L.benchmark("rve_paths/designed"))
    # config/tiny.yaml solves with the autodiff tangent: FEM–ML reads NNσ only, and ND's training is
    # not part of its cost
    assert list(plan.fem_ml_models()) == ["sigma"]
    for network in ("dataset", "train_sigma"):
        expected[network] = tables.benchmark_seconds(L.benchmark(f"surrogate/{network}"))
    assert len(items) == len(expected) == (5 if reference == "dem" else 4)
    assert not any("train_tangent" in label for label in items.index)
    for key, seconds in expected.items():
        matching = [label for label in items.index if label.startswith(key) or f"rule {key})" in label]
        assert len(matching) == 1, (key, list(items.index))
        assert items[matching[0]] == pytest.approx(seconds, rel=1e-6) and seconds > 0, key
    total = float(cost[cost["kind"] == "surrogate cost total"]["wall_time_s"].iloc[0])
    assert total == pytest.approx(sum(expected.values()))
    assert headline["surrogate_cost_s"] == pytest.approx(total)
    t_ref, t_ml = cost[cost["kind"] == "one answer"]["wall_time_s"].tolist()
    assert t_ref == pytest.approx(headline["reference_wall_time_s"])
    assert t_ml == pytest.approx(headline["surrogate_wall_time_s"] / (n_ml - 1) * (n_ref - 1))
    assert headline["break_even_runs"] == tables.break_even_runs(total, t_ref, t_ml)
    assert f"Making the surrogate took {display['surrogate_cost']}" in page
    if headline["break_even_runs"] is None:
        assert "It never pays back here" in page
    else:
        n = headline["break_even_runs"]
        assert f"It pays back from {display['break_even_runs']} FEM–ML run{'' if n == 1 else 's'} of path2 on" in page
        assert n * t_ml + total <= n * t_ref and (n == 1 or (n - 1) * t_ml + total > (n - 1) * t_ref)


# -- the front page and the headline page (fast: no job runs) -----------------------------

API_REPORT = """
import sys
from pathlib import Path
from snakemake.api import SnakemakeApi
from snakemake.report.html_reporter import ReportSettings
from snakemake.settings.types import ConfigSettings, DAGSettings, OutputSettings, ResourceSettings
from granular_multiscale.plan import Layout
root, out, report = map(Path, sys.argv[1:4])
with SnakemakeApi(OutputSettings()) as api:
    workflow = api.workflow(resource_settings=ResourceSettings(), snakefile=root / "Snakefile", workdir=root,
                            config_settings=ConfigSettings(configfiles=[root / "config/tiny.yaml"],
                                                           config={"output_dir": str(out), "reference_material": sys.argv[4]}))
    # a target with no report() output upstream: the report holds the front page only
    workflow.dag(DAGSettings(targets={Layout(out).packing_summary()})).create_report(
        reporter="html", report_settings=ReportSettings(path=report))
"""


def headline_file(out, **changes):
    from granular_multiscale.analysis.products import headline_display

    headline = {
        "output_dir": str(out), "reference_material": "dem", "reference": "FEM–DEM (150 spheres)",
        "surrogate": "FEM–ML (nn tangent)", "validation_path": "path2", "training_path": "path1",
        "elements": [1, 1, 2], "gauss_points": 16, "mesh_elements": [1, 1, 2], "symmetry": "none",
        "modelled_fraction": 1.0, "uniform_field": False, "gauss_points_modelled": 16,
        "material_points_evaluated": 16, "surrogate_points_evaluated": 16, "n_spheres": 150,
        "machine": {"cores": 2, "cpu": "Test CPU 9000", "memory_gib": 24.0, "system": "Linux"},
        "reference_wall_time_s": 563.2, "surrogate_wall_time_s": 0.247, "speedup": 2280.2, "surrogate_completed": True,
        "surrogate_load_steps": 57, "reference_load_steps": 57, "top_force_max_rel_pct": 2.414,
        "stress_mae_heldout_kpa": 1.951, "ablation": "FEM–ML, no history", "ablation_top_force_max_rel_pct": 5.02,
        "ablation_stress_mae_heldout_kpa": 3.01, "surrogate_cost_s": 1000.0,
        "surrogate_cost_items": [{"item": "RVE preparation (YADE packings)", "wall_time_s": 100.0},
                                 {"item": "training NNσ (rule train_sigma)", "wall_time_s": 900.0}],
        "break_even_runs": 2,
        **changes,
    }
    headline["display"] = headline_display(headline)
    (out / "tables").mkdir(parents=True, exist_ok=True)
    (out / "tables" / "headline.json").write_text(json.dumps(headline))
    return headline


def test_the_front_page_states_no_number_of_a_run_whatever_builds_the_report(tmp_path):
    """Pass criterion: the front page is rendered from the config alone. Built through the API
    (no '--report' on any command line) from an output directory that holds a headline.json, it
    states none of its numbers, and, with no headline page among the report's items, says where
    the numbers come from; the reStructuredText renders without errors."""
    out, report = tmp_path / "out", tmp_path / "report.html"
    headline_file(out)
    result = subprocess.run([sys.executable, "-c", API_REPORT, str(ROOT), str(out), str(report), "dem"],
                            cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-4000:]
    raw = json.loads(re.search(r"var workflow_desc = (\".*?\");\n", report.read_text()).group(1))
    assert "System Message" not in raw
    page = plain(raw)
    assert "YADE RVEs of 150 spheres" in page and "Reductions configured: symmetry none, uniform field false." in page
    assert "Not in this report: its targets do not include tables/headline.json" in page
    for number in ("Test CPU 9000", "2,280", "563 s", "2.41 %", "Measured on"):
        assert number not in page, number


def test_the_headline_page_states_the_headline(tmp_path):
    """The headline page: numbers as people read them, what ran, the cost of the surrogate and
    its break-even."""
    from granular_multiscale.analysis.products import headline_page

    page = page_text(headline_page(headline_file(tmp_path)))
    assert "Measured on 2 cores of Test CPU 9000" in page
    assert "Speedup 2,280× for one answer: FEM–ML (nn tangent) took 0.247 s, FEM–DEM (150 spheres) 563 s (9.4 min)" in page
    assert "the full specimen, 16 Gauss points (no symmetry reduction)" in page
    assert "the reference evaluated 16 RVEs, one per Gauss point" in page
    assert ("Making the surrogate took 1,000 s (17 min): RVE preparation (YADE packings) 100 s; "
            "training NNσ (rule train_sigma) 900 s (15 min).") in page
    assert "It pays back from 2 FEM–ML runs of path2 on" in page
    assert "Top-force error 2.41 % of the peak" in page and "Held-out stress MAE 1.95 kPa" in page
    assert "top-force error 5.02 %, held-out stress MAE 3.01 kPa" in page
    assert "e+0" not in page  # no exponent notation anywhere


def test_the_headline_page_states_the_reductions_and_a_surrogate_that_never_pays_back(tmp_path):
    """Quarter symmetry with a uniform field on the elastoplastic reference: 16 of the 64 Gauss
    points modelled, one material point evaluated; FEM–ML slower than the analytic model."""
    from granular_multiscale.analysis.products import headline_page

    headline = headline_file(tmp_path, reference_material="elastoplastic",
                             reference="FEM, elastoplastic model (reference)", elements=[2, 2, 2], gauss_points=64,
                             symmetry="quarter", modelled_fraction=0.25, uniform_field=True,
                             material_points_evaluated=1, reference_wall_time_s=0.31, surrogate_wall_time_s=1.2,
                             speedup=0.2583, break_even_runs=None,
                             surrogate_cost_items=[{"item": "dataset", "wall_time_s": 3.0}], surrogate_cost_s=3.0)
    page = page_text(headline_page(headline))
    assert "quarter symmetry (specimen.symmetry: quarter), a mesh of 1 × 1 × 2 elements with 16 of the specimen's 64 Gauss points" in page
    assert "uniform field (specimen.uniform_field: true): one material point stands for all 16 Gauss points" in page
    assert "the reference evaluated 1 material point;" in page
    assert "Speedup 0.258× for one answer" in page
    assert "It never pays back here: FEM–ML (nn tangent) is not faster than FEM, elastoplastic model (reference)." in page
    assert "The reference is the analytic model, not FEM–DEM" in page


def test_a_config_with_a_headline_key_is_refused_naming_it():
    """The workflow keeps no number of a run in its config: 'headline' is no setting, and a config
    that carries one is refused like any unknown key, naming it."""
    from granular_multiscale.config import ConfigError, validate_config

    with pytest.raises(ConfigError, match=r"'headline' was unexpected\) \(unknown key"):
        validate_config({"output_dir": "results/x", "headline": {"speedup": 2660.3}})
