"""The workflow's job graph, dry-run (`snakemake -n`): what `all` schedules for a configuration."""

import re
import subprocess
import sys
from pathlib import Path

from granular_multiscale.plan import Layout

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = str(Path(sys.executable).with_name("snakemake"))


def test_other_sphere_counts_add_their_own_packing_and_fem_dem_run(tmp_path):
    """Pass criterion: with analysis.fem_dem_sphere_counts = [60] (given on the command line, as a
    user would), `all` schedules rve_spheres and fem_dem_spheres for 60 spheres, on the validation
    path only, and feeds that run to the speedup and accuracy tables."""
    out = tmp_path / "tiny"
    command = [SNAKEMAKE, "-n", "all", "--configfile", "config/tiny.yaml", "--config", f"output_dir={out}",
               "analysis={fem_dem_sphere_counts: [60]}"]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-3000:]
    L = Layout(out)
    assert f"output: {L.packings(1, 60)[0]}, {L.packing_summary(60)}" in output
    assert f"output: {L.run('fem_dem_n60', 'path2')}" in output
    assert L.run("fem_dem_n60", "path1") not in output
    speedup_inputs = [line for line in output.splitlines() if line.strip().startswith("input:") and
                      L.run("fem_dem_n60", "path2") in line]
    assert len(speedup_inputs) == 2  # table_speedup and table_accuracy
    assert not out.exists()


def test_adaptive_runs_join_all_only_with_adaptive_report(tmp_path):
    """Pass criterion: by default `all` schedules no adaptive run; with adaptive.report (and the
    thresholds given on the command line, .inf included) it schedules one per threshold on the
    validation path, feeds them to the speedup and accuracy tables and draws the mode map."""
    out = tmp_path / "tiny"
    base = [SNAKEMAKE, "-n", "all", "--configfile", "config/tiny.yaml", "--config", f"output_dir={out}"]

    def dry_run(*extra):
        result = subprocess.run(base + list(extra), cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert result.returncode == 0, (result.stdout + result.stderr)[-3000:]
        return result.stdout + result.stderr

    default = dry_run()
    assert "rule adaptive:" not in default and "adaptive_mode_map" not in default
    output = dry_run("adaptive={report: true, thresholds: [0.02, .inf]}")
    L = Layout(out)
    for label in ("t0.02", "tinf"):
        assert f"output: {L.adaptive(label, 'path2')}" in output
        assert L.adaptive(label, "path1") not in output
    assert f"output: {L.figure('adaptive_mode_map.png')}" in output
    tables = [line for line in output.splitlines() if line.strip().startswith("input:") and
              L.adaptive("tinf", "path2") in line]
    assert len(tables) == 3  # table_speedup, table_accuracy, figure_mode_map
    assert not out.exists()


def test_the_default_scale_runs_the_adaptive_curve_in_all(tmp_path):
    """Pass criterion: config/config.yaml (the Snakefile's own) makes `all` run the validation path
    at each of its adaptive thresholds with its control (adaptive.controls), each problem's adaptive
    run at threshold .inf with its control, and draw the mode map; FEM–ML's biaxial test reads the
    weak zone's networks, trained on the sets band_weak and band_weak_cycles of the weak packing."""
    out = tmp_path / "default"
    command = [SNAKEMAKE, "-n", "all", "--config", f"output_dir={out}"]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-3000:]
    runs = sorted(line.split("output: ")[1].split(",")[0] for line in output.splitlines()
                  if "output: " in line and f"{out}/adaptive/" in line)  # Path2's, not the problems'
    L = Layout(out)
    assert runs == [L.adaptive(label, "path2") for label in ("t0.01", "t0.01_elastoplastic", "t0.02",
                                                             "t0.02_elastoplastic")]
    for problem in ("biaxial", "footing"):
        assert f"output: {L.problem_run(problem, 'adaptive', problem)}" in output
        assert f"output: {L.problem_run(problem, 'control_elastoplastic', problem)}" in output
    assert f"output: {L.figure('adaptive_mode_map.png')}" in output
    # the biaxial test's weak zone: its own networks, trained on the weak packing's RVE paths, in FEM–ML
    jobs = re.split(r"^(?:local)?rule ", output, flags=re.M)
    for name in ("band_weak", "band_weak_cycles"):
        weak_set = next(job for job in jobs if f"output: {L.rve_paths(name)}" in job)
        assert f"input: {L.weak_packing()}\n" in weak_set
    # with the default autodiff tangent FEM–ML reads the NNσ only; ND is read where a run is solved with it
    fem_ml = next(job for job in jobs if f"output: {L.problem_run('biaxial', 'fem_ml', 'biaxial')}" in job)
    assert L.model("sigma", "weak_zone/") in fem_ml and L.model("tangent", "weak_zone/") not in fem_ml
    assert L.model("tangent") not in fem_ml
    as_reference = next(job for job in jobs
                        if f"output: {L.problem_run('biaxial', 'fem_ml_as_reference', 'biaxial')}" in job)
    assert L.model("tangent", "weak_zone/") in as_reference and L.model("tangent") in as_reference
    footing = next(job for job in jobs if f"output: {L.problem_run('footing', 'fem_ml', 'footing')}" in job)
    assert "weak_zone/" not in footing
    assert not out.exists()


# Loads the workflow and plans `all` with snakemake's command line, in this process, and lists
# every file under the output directory (argv[1]) that anything opened meanwhile, but the output
# lock (.workflow.lock: whether another workflow holds the directory).
LOAD_AND_PLAN = """
import os
import sys

out = os.path.realpath(sys.argv[1])
opened = []


def audit(event, args):
    if event == "open" and isinstance(args[0], (str, bytes, os.PathLike)):
        path = os.path.realpath(os.fsdecode(args[0]))
        if path.startswith(out + os.sep) and os.path.basename(path) != ".workflow.lock":
            opened.append(path)


sys.addaudithook(audit)
from snakemake.cli import main

try:
    main(sys.argv[2:])
except SystemExit as done:
    code = done.code
print("OPENED:", sorted(set(opened)))
sys.exit(code)
"""


def test_loading_the_workflow_reads_no_result_file(tmp_path):
    """Pass criterion: the rule files only declare rules. With a damaged tables/headline.json and
    tables/tolerance_study.csv in the output directory (written by hand: no checksum beside them),
    `snakemake -n all` loads and plans without opening either, warns about neither, and plans the
    headline job that rewrites them: no number of a run goes into the config."""
    out = tmp_path / "tiny"
    (out / "tables").mkdir(parents=True)
    (out / "tables" / "headline.json").write_text("{not json")
    (out / "tables" / "tolerance_study.csv").write_text("not,a\nstudy")
    args = ["-n", "all", "--configfile", "config/tiny.yaml", "--config", f"output_dir={out}"]
    result = subprocess.run([sys.executable, "-c", LOAD_AND_PLAN, str(out), *args], cwd=ROOT, capture_output=True,
                            text=True, timeout=300)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-3000:]
    assert "OPENED: []" in result.stdout, output[-3000:]
    assert "headline" not in "\n".join(line for line in output.splitlines() if "arning" in line)
    L = Layout(str(out))
    assert f"output: {L.table('headline.json')}, {L.table('headline.html')}" in output
    assert (out / "tables" / "headline.json").read_text() == "{not json"
    assert sorted(p.name for p in (out / "tables").iterdir()) == ["headline.json", "tolerance_study.csv"]


def test_a_set_at_another_consolidation_pressure_gets_packings_of_its_own(tmp_path):
    """A training set with consolidation_pressure 0.5: `all` schedules rve_pressure for rve_p0.5/ and
    feeds that packing to the set's rule rve_paths; the specimen's packing stays that of rule rve."""
    out = tmp_path / "tiny"
    config = tmp_path / "p0.yaml"
    config.write_text(f"output_dir: {out}\n"
                      "rve_paths: {sets: {low: {triaxial: 2, n_steps: 5, consolidation_pressure: 0.5}}}\n"
                      "surrogate: {training_sources: [path1, 'rve_paths:low'], history_variables: [phi1, phi2, p0]}\n")
    command = [SNAKEMAKE, "-n", "all", "--configfile", "config/tiny.yaml", str(config)]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-3000:]
    L = Layout(out)
    packing = L.packings(1, pressure="0.5")[0]
    assert f"output: {packing}, {L.packing_summary(pressure='0.5')}" in output
    assert re.search(rf"input: {re.escape(packing)}\n\s+output: {re.escape(L.rve_paths('low'))}", output), output[-3000:]
    assert f"output: {L.packings(1)[0]}, {L.packing_summary()}" in output
