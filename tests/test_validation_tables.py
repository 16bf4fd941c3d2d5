"""Validation per load path and load phase (analysis/validation.py, rule validation_tables):
cycle-numbered phases, the table's numbers against known perturbations of a real run, a run that
stopped early, and the rule's place in `all`.

The runs are the elastoplastic reference of the tiny mesh on path3 of config/new_paths.yaml (two
unload–reload cycles; well under a second) and copies of it with known errors added to chosen
steps, so every number of the table is known exactly."""

import io
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from granular_multiscale.analysis import products, validation
from granular_multiscale.config import validate_config
from granular_multiscale.data import read_run, write_run
from granular_multiscale.drivers.reference import run_fem_reference
from granular_multiscale.paths import load_paths_from_config, number_cycles
from granular_multiscale.plan import Layout

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = str(Path(sys.executable).with_name("snakemake"))
NEW_PATHS = yaml.safe_load((ROOT / "config" / "new_paths.yaml").read_text())["load_paths"]


def numbered(path_name):
    return load_paths_from_config({"load_paths": NEW_PATHS})[path_name].phase_cycle()


def spans(labels):
    """{label: (first step, last step)} of per-step labels whose runs are contiguous."""
    out = {}
    for step, label in enumerate(labels):
        first, _ = out.get(label, (step, step))
        assert label not in out or out[label][1] == step - 1, f"{label} is not contiguous"
        out[label] = (first, step)
    return out


def test_cycle_numbered_phases_of_path3_and_path4():
    """Pass criterion: each unloading and the reloading after it carry the cycle's number, at the
    steps the segments say (path3: 13 loading, 6 unloading, 19 reloading, 9, 22 steps), and
    dropping the numbers gives LoadPath.phase() back."""
    assert spans(numbered("path3")) == {"initial": (0, 0), "loading": (1, 13), "unloading 1": (14, 19),
                                        "reloading 1": (20, 38), "unloading 2": (39, 47), "reloading 2": (48, 69)}
    path4 = spans(numbered("path4"))
    assert list(path4) == ["initial", "loading", "unloading 1", "reloading 1", "unloading 2", "reloading 2",
                           "unloading 3", "reloading 3", "unloading 4", "reloading 4"]
    assert path4["unloading 1"] == (11, 13) and path4["unloading 4"] == (59, 61) and path4["reloading 4"] == (62, 69)
    paths = load_paths_from_config({"load_paths": NEW_PATHS})
    for path in paths.values():
        assert [label.split()[0] for label in path.phase_cycle()] == list(path.phase())
    assert spans(paths["path2"].phase_cycle())["unloading 1"] == (10, 15)


@pytest.fixture(scope="module")
def reference_file(tmp_path_factory):
    """The elastoplastic reference run of path3 on the tiny mesh."""
    config = yaml.safe_load((ROOT / "config" / "tiny.yaml").read_text())
    config.update(reference_material="elastoplastic", load_paths=NEW_PATHS)
    out = tmp_path_factory.mktemp("validation") / "fem_elastoplastic" / "path3.h5"
    run_fem_reference(validate_config(config), "path3", str(out))
    return out


def perturbed(reference, *, force=None, volume=None, stress=None):
    """A copy of the reference with errors added: ``force`` = (fraction of the peak |F|, phases),
    ``volume`` likewise of the peak |εv|, ``stress`` = (Pa added to every component, phases)."""
    run = reference.copy(deep=True)
    phases = number_cycles(reference["phase"].values)
    for name, change in (("top_force", force), ("volumetric_strain", volume)):
        if change:
            fraction, where = change
            pick = np.isin(phases, where)
            run[name].values[pick] += fraction * np.abs(reference[name].values).max()
    if stress:
        pa, where = stress
        run["stress"].values[np.isin(phases, where)] += pa
    run.attrs.update(method="fem_ml", completed=1)
    return run


def write_cases(tmp_path, reference_file, runs, role="validation path"):
    files = {"reference": str(reference_file)}
    for label, run in runs.items():
        files[label] = str(write_run(run, tmp_path / f"{label}.h5"))
    csv, html = tmp_path / "validation_by_phase.csv", tmp_path / "validation_by_phase.html"
    table = products.make_validation_table([("path3", role, files)], csv, html, reference_label="reference")
    pd.testing.assert_frame_equal(table, pd.read_csv(csv, keep_default_na=True), check_dtype=False, check_exact=False)
    return table.set_index(["method", "phase"]), html.read_text()


def test_the_table_reports_known_errors_per_phase(tmp_path, reference_file):
    """Pass criterion: +2 % of the peak top force in the unloading steps gives 2.00 % (max and mean)
    in both unloadings and 0.00 % elsewhere; +3 % of the peak |εv| in the second unloading only
    gives 3.00 % there; +1 kPa on every stress component in the second reloading gives an MAE of
    1.000 kPa there; 'all' averages over the 69 load steps; an exact copy gives zeros."""
    reference = read_run(reference_file)
    ml = perturbed(reference, force=(0.02, ["unloading 1", "unloading 2"]), volume=(0.03, ["unloading 2"]),
                   stress=(1000.0, ["reloading 2"]))
    table, html = write_cases(tmp_path, reference_file, {"FEM–ML": ml, "exact copy": perturbed(reference)})
    assert list(table.loc["FEM–ML"].index) == ["initial", "loading", "unloading 1", "reloading 1", "unloading 2",
                                               "reloading 2", "all"]
    row = table.loc["FEM–ML"]
    assert row["steps"].tolist() == row["steps_in_phase"].tolist() == [1, 13, 6, 19, 9, 22, 69]
    assert (row["completed"] == "yes").all() and (row["load_steps_reached"] == 69).all()
    for phase in ("unloading 1", "unloading 2"):
        assert row.loc[phase, "top_force_max_pct"] == pytest.approx(2.0, abs=1e-9)
        assert row.loc[phase, "top_force_mean_pct"] == pytest.approx(2.0, abs=1e-9)
    for phase in ("initial", "loading", "reloading 1", "reloading 2"):
        assert row.loc[phase, "top_force_max_pct"] == pytest.approx(0.0, abs=1e-9)
    assert row.loc["all", "top_force_max_pct"] == pytest.approx(2.0, abs=1e-9)
    assert row.loc["all", "top_force_mean_pct"] == pytest.approx(2.0 * 15 / 69, abs=1e-9)
    assert row["volumetric_strain_max_pct"].round(9).tolist() == [0, 0, 0, 0, 3, 0, 3]
    assert row.loc["reloading 2", "stress_mae_kpa"] == pytest.approx(1.0, abs=1e-9)
    assert row.loc["unloading 2", "stress_mae_kpa"] == pytest.approx(0.0, abs=1e-9)
    assert row.loc["all", "stress_mae_kpa"] == pytest.approx(22 / 69, abs=1e-9)
    copy = table.loc["exact copy", ["top_force_max_pct", "volumetric_strain_max_pct", "stress_mae_kpa"]]
    assert np.abs(copy.to_numpy()).max() == 0.0
    # the HTML: readable numbers, no grey (training) rows
    assert "<td>unloading 2</td><td>9 of 9</td><td>yes</td><td>2.00</td><td>2.00</td><td>3.00</td><td>0.00</td>" in html
    assert 'class="reference"' not in html and "e-0" not in html


def test_a_run_that_stopped_early_is_compared_over_its_steps_and_flagged(tmp_path, reference_file):
    """Pass criterion: a run that kept steps 0..29 (completed = 0) has every loading and
    unloading-1 step, 10 of the 19 reloading-1 steps, none of the second cycle (no errors there),
    says 'no: stopped after step 29 of 69', and its errors are those of the steps it reached."""
    reference = read_run(reference_file)
    partial = perturbed(reference, force=(0.01, ["reloading 1"])).isel(step=slice(0, 30))
    partial.attrs.update(completed=0, stopped_at_step=30)
    table, html = write_cases(tmp_path, reference_file, {"FEM–ML": partial}, role="training path")
    row = table.loc["FEM–ML"]
    assert row["steps"].tolist() == [1, 13, 6, 10, 0, 0, 29]
    assert row["steps_in_phase"].tolist() == [1, 13, 6, 19, 9, 22, 69]
    assert (row["completed"] == "no").all() and (row["load_steps_reached"] == 29).all()
    assert row.loc["reloading 1", "top_force_max_pct"] == pytest.approx(1.0, abs=1e-9)
    assert row.loc["all", "top_force_mean_pct"] == pytest.approx(10 / 29, abs=1e-9)
    assert row.loc[["unloading 2", "reloading 2"], "top_force_max_pct"].isna().all()
    assert "<td>reloading 1</td><td>10 of 19</td><td>no: stopped after step 29 of 69</td><td>1.00</td>" in html
    assert "<td>unloading 2</td><td>0 of 9</td><td>no: stopped after step 29 of 69</td><td>–</td>" in html
    assert html.count('class="reference"') == 7  # a training path: every row grey


def test_a_short_run_that_claims_to_be_complete_is_refused(tmp_path, reference_file):
    """Pass criterion: the error names the method, the path and the run file."""
    reference = read_run(reference_file)
    short = perturbed(reference).isel(step=slice(0, 30))
    with pytest.raises(ValueError, match=r"FEM–ML on path3: 30 steps, the reference has 70 \(run files: .*FEM–ML.h5"):
        write_cases(tmp_path, reference_file, {"FEM–ML": short})
    with pytest.raises(ValueError, match="role 'held out' of path path3"):
        validation.phase_errors(reference, {}, path="path3", role="held out")


# -- the rule in the workflow (dry runs) -----------------------------------------------------


def dry_run(tmp_path, *configfiles):
    out = tmp_path / "out"
    command = [SNAKEMAKE, "-n", "all", "--configfile", *configfiles, "--config", f"output_dir={out}"]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-3000:]
    assert not out.exists()
    lines = output.splitlines()
    rule = lines.index("rule validation_tables:")
    inputs = lines[rule + 1].split("input:", 1)[1].split(", ")
    outputs = [line.split("output:", 1)[1].strip() for line in lines if line.strip().startswith("output:")]
    return out, [name.strip() for name in inputs], outputs


def test_validation_tables_is_part_of_all_at_the_tiny_scale(tmp_path):
    """Pass criterion: `all` schedules validation_tables with the reference, FEM–ML and no-history
    runs of the validation path path2, then of the training path path1."""
    out, inputs, outputs = dry_run(tmp_path, "config/tiny.yaml")
    L = Layout(out)
    assert f"{L.table('validation_by_phase.csv')}, {L.table('validation_by_phase.html')}" in outputs
    assert inputs == [L.run(run, path) for path in ("path2", "path1") for run in ("fem_dem", "fem_ml", "fem_ml_nohist")]


def test_the_new_paths_are_validation_paths_of_all(tmp_path):
    """Pass criterion: with config/new_paths.yaml merged over config/config.yaml, `all` schedules
    the FEM–DEM and both FEM–ML runs of path3 and path4, and the validation table compares them
    (validation paths path2, path3, path4, then the training path path1)."""
    out, inputs, outputs = dry_run(tmp_path, "config/config.yaml", "config/new_paths.yaml")
    L = Layout(out)
    for path in ("path3", "path4"):
        for run in ("fem_dem", "fem_ml", "fem_ml_nohist"):
            assert L.run(run, path) in outputs
    assert inputs == [L.run(run, path) for path in ("path2", "path3", "path4", "path1")
                      for run in ("fem_dem", "fem_ml", "fem_ml_nohist")]


CAPTIONS = sorted(path.name for path in (ROOT / "workflow" / "report").glob("*.rst"))


@pytest.mark.parametrize("name", CAPTIONS)
def test_the_captions_are_valid_restructuredtext(name):
    """Pass criterion: docutils renders every caption of the report without a warning (a bare
    |F| would be an undefined substitution, shown in the report as an error box). In a caption
    that is a Jinja template the fixed text is checked: macros, statements and comments
    dropped, each expression "x"; links to the report's categories are left to the report (test_report)."""
    from docutils.core import publish_parts

    template = (ROOT / "workflow" / "report" / name).read_text()
    text = re.sub(r"{%-?\s*macro.*?endmacro\s*-?%}", "", template, flags=re.S)
    text = re.sub(r"{{.*?}}", "x", re.sub(r"{%.*?%}|{#.*?#}", "", text, flags=re.S), flags=re.S)
    messages = io.StringIO()
    parts = publish_parts(text, writer="html", settings_overrides={"halt_level": 5, "report_level": 2, "warning_stream": messages})
    problems = [line for line in messages.getvalue().splitlines() if "(WARNING/" in line or "(ERROR/" in line or "(SEVERE/" in line]
    assert [line for line in problems if "Unknown target name" not in line] == []
    assert not name.startswith("validation_by_phase.") or "What to look for" in parts["body"]
