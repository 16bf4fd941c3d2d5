"""The workflow's job graph, dry-run (`snakemake -n`): what `all` schedules for a configuration."""

import subprocess
import sys
from pathlib import Path

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
    assert f"output: {out}/rve_n60/packing_0.yade.gz, {out}/rve_n60/summary.json" in output
    assert f"output: {out}/fem_dem_n60/path2.h5" in output
    assert f"{out}/fem_dem_n60/path1.h5" not in output
    speedup_inputs = [line for line in output.splitlines() if line.strip().startswith("input:") and
                      f"{out}/fem_dem_n60/path2.h5" in line]
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
    for label in ("t0.02", "tinf"):
        assert f"output: {out}/adaptive/{label}/path2.h5" in output
        assert f"{out}/adaptive/{label}/path1.h5" not in output
    assert f"output: {out}/figures/adaptive_mode_map.png" in output
    tables = [line for line in output.splitlines() if line.strip().startswith("input:") and
              f"{out}/adaptive/tinf/path2.h5" in line]
    assert len(tables) == 3  # table_speedup, table_accuracy, figure_mode_map
    assert not out.exists()


def test_the_default_scale_runs_the_adaptive_curve_in_all(tmp_path):
    """Pass criterion: config/config.yaml (the Snakefile's own) makes `all` run the validation path
    at each of its adaptive thresholds with its control (adaptive.controls), and nothing else
    adaptive (not the problems' adaptive runs: adaptive.problems is false), and draw the mode map."""
    out = tmp_path / "default"
    command = [SNAKEMAKE, "-n", "all", "--config", f"output_dir={out}"]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-3000:]
    runs = sorted(line.split("output: ")[1].split(",")[0] for line in output.splitlines()
                  if "output: " in line and "/adaptive/" in line)
    assert runs == [f"{out}/adaptive/t0.01/path2.h5", f"{out}/adaptive/t0.01_elastoplastic/path2.h5",
                    f"{out}/adaptive/t0.02/path2.h5", f"{out}/adaptive/t0.02_elastoplastic/path2.h5"]
    assert "/biaxial/adaptive_t" not in output and "/footing/control_" not in output
    assert f"output: {out}/figures/adaptive_mode_map.png" in output
    assert not out.exists()
