"""The shipped scale configs as Snakemake loads them: the Snakefile's `configfile:
config/config.yaml` first, then `--configfile config/<scale>.yaml` merged over it. A scale file
must mean exactly what it says: nothing it leaves out of config/config.yaml may change what
its scale runs (the paper scale once inherited `analysis.fem_dem_sphere_counts: [100]`, one
more 2000-RVE FEM–DEM run nobody asked for)."""

import copy
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from snakemake.utils import update_config

from granular_multiscale.config import validate_config

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = str(Path(sys.executable).with_name("snakemake"))
SCALES = ["tiny.yaml", "paper.yaml", "elastoplastic.yaml"]


def read(name):
    return yaml.safe_load((ROOT / "config" / name).read_text())


def as_snakemake_loads(name):
    """config/config.yaml with the scale file merged over it, as Snakemake does (update_config)."""
    config = copy.deepcopy(read("config.yaml"))
    update_config(config, read(name))
    return config


def differences(a, b, prefix=""):
    keys = sorted(set(a) | set(b))
    out = []
    for key in keys:
        if isinstance(a.get(key), dict) and isinstance(b.get(key), dict):
            out += differences(a[key], b[key], f"{prefix}{key}.")
        elif a.get(key) != b.get(key):
            out.append(f"{prefix}{key}: {a.get(key)!r} alone, {b.get(key)!r} merged over config/config.yaml")
    return out


@pytest.mark.parametrize("name", SCALES)
def test_a_scale_file_means_what_it_says(name):
    """Pass criterion: the scale file alone (schema defaults for what it leaves out) and the scale
    file merged over config/config.yaml give the same validated config, key by key."""
    alone = validate_config(read(name))
    merged = validate_config(as_snakemake_loads(name))
    assert differences(alone, merged) == [], f"config/{name} inherits from config/config.yaml"


def test_the_scales_state_their_fem_dem_runs_and_workers():
    paper, tiny = as_snakemake_loads("paper.yaml"), as_snakemake_loads("tiny.yaml")
    assert paper["analysis"]["fem_dem_sphere_counts"] == [] and paper["dem"]["n_workers"] == 64
    assert read("paper.yaml")["analysis"]["fem_dem_sphere_counts"] == []
    assert tiny["analysis"]["fem_dem_sphere_counts"] == [100] == read("tiny.yaml")["analysis"]["fem_dem_sphere_counts"]
    assert read("tiny.yaml")["dem"]["n_workers"] == 2


def dry_run(tmp_path, name):
    out = tmp_path / "out"
    command = [SNAKEMAKE, "-n", "-j2", "all", "--configfile", f"config/{name}", "--config", f"output_dir={out}"]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-3000:]
    assert not out.exists()
    jobs = [line.split()[1].rstrip(":") for line in output.splitlines() if line.startswith(("rule ", "localrule "))]
    return jobs, output


def test_the_paper_scale_schedules_one_fem_dem_run_per_path_and_no_other_sphere_count(tmp_path):
    """Pass criterion: `snakemake -n all --configfile config/paper.yaml` lists the packing and the
    FEM–DEM runs of path1 and path2 with 1000 spheres, and no rve_spheres / fem_dem_spheres job."""
    jobs, output = dry_run(tmp_path, "paper.yaml")
    assert jobs.count("rve") == 1 and jobs.count("fem_dem") == 2
    assert "rve_spheres" not in jobs and "fem_dem_spheres" not in jobs
    assert "fem_dem_n" not in output and "rve_n" not in output


def test_the_elastoplastic_scale_runs_no_dem(tmp_path):
    jobs, _ = dry_run(tmp_path, "elastoplastic.yaml")
    assert jobs.count("fem_elastoplastic") == 2
    assert not {"rve", "fem_dem", "rve_spheres", "fem_dem_spheres"} & set(jobs)
