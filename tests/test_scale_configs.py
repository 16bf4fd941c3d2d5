"""The shipped scale configs as Snakemake loads them: the Snakefile's `configfile:
config/config.yaml` first, then `--configfile config/<scale>.yaml` merged over it. A scale file
must mean exactly what it says: nothing it leaves out of config/config.yaml may change what
its scale runs (the paper scale once inherited `analysis.fem_dem_sphere_counts: [100]`, one
more 2000-RVE FEM–DEM run nobody asked for)."""

import copy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from snakemake.utils import update_config

from granular_multiscale.config import validate_config

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = str(Path(sys.executable).with_name("snakemake"))
SCALES = ["tiny.yaml", "paper.yaml", "elastoplastic.yaml"]


def read(name):
    return yaml.safe_load((ROOT / "config" / name).read_text())


def as_snakemake_loads(*names):
    """config/config.yaml with the given files merged over it in order, as Snakemake does
    (update_config) with the Snakefile's configfile and several --configfile files."""
    config = copy.deepcopy(read("config.yaml"))
    for name in names:
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


@pytest.mark.parametrize("scale", ["config.yaml", "tiny.yaml"])
def test_new_paths_add_path3_and_path4_and_keep_path1_and_path2(scale):
    """Pass criterion: config/new_paths.yaml merged over a scale (as `--configfile config/<scale>
    config/new_paths.yaml` does) leaves everything but load_paths as the scale alone has it, keeps
    path1 and path2 exactly as the schema defaults (their runs are reused), and adds path3 (two
    unload–reload cycles: peaks 1.5 % and 3 %, valleys 0.8 % and 2 %) and path4 (four cycles to
    1, 2, 3, 4 %, each unloaded by 0.3 %), both ending at 4.5 %, under 70 steps of about 1e-3,
    and neither a training path."""
    from granular_multiscale.paths import load_paths_from_config

    alone = validate_config(as_snakemake_loads(scale))
    with_new = validate_config(as_snakemake_loads(scale, "new_paths.yaml"))
    assert differences({k: v for k, v in alone.items() if k != "load_paths"},
                       {k: v for k, v in with_new.items() if k != "load_paths"}) == []
    assert list(with_new["load_paths"]) == ["path1", "path2", "path3", "path4"]
    assert {k: with_new["load_paths"][k] for k in ("path1", "path2")} == alone["load_paths"]
    # neither new path trains: the training sources name load paths path1 at most (and RVE-path sets)
    sources = with_new["surrogate"]["training_sources"] or [with_new["training_path"]]
    assert not {"path3", "path4"} & set(sources) and "path1" in sources

    paths = load_paths_from_config(with_new)
    shapes = {}
    for name in ("path3", "path4"):
        path = paths[name]
        strain = path.axial_strain()
        reversals = path.reversal_steps()
        turning = strain[np.asarray(reversals) - 1]  # the strain where each reversal starts
        shapes[name] = (len(reversals), turning[0::2].round(6).tolist(), turning[1::2].round(6).tolist())
        assert path.n_steps < 70 and strain[-1] == pytest.approx(0.045)
        assert 0.9e-3 < np.abs(path.increments()).min() <= np.abs(path.increments()).max() < 1.2e-3
    assert shapes == {"path3": (4, [0.015, 0.03], [0.008, 0.02]),
                      "path4": (8, [0.01, 0.02, 0.03, 0.04], [0.007, 0.017, 0.027, 0.037])}


@pytest.mark.parametrize("name, trajectories", [("pressure_input.yaml", 32), ("pressure_input_more.yaml", 96)])
def test_pressure_input_adds_three_consolidation_pressures_and_keeps_the_default_sets(name, trajectories):
    """Pass criterion: config/pressure_input.yaml (and its variant with more data) over the default
    scale keeps every default RVE-path set as it is (their files are reused), adds sets of 32 (96)
    trajectories at 0.4, 2 and 4 p0 to the training sources, gives the networks p0, and changes
    nothing else but the output folder."""
    alone = validate_config(as_snakemake_loads("config.yaml"))
    with_p0 = validate_config(as_snakemake_loads("config.yaml", name))
    sets = with_p0["rve_paths"]["sets"]
    assert {k: sets[k] for k in alone["rve_paths"]["sets"]} == alone["rve_paths"]["sets"]
    added = set(sets) - set(alone["rve_paths"]["sets"])
    assert {k: sets[k]["consolidation_pressure"] for k in added} == {"p040": 0.4, "p200": 2.0, "p400": 4.0}
    families = ("triaxial", "axisymmetric", "random_walk", "proportional", "plane_strain", "isotropic_triaxial")
    assert {k: sum(sets[k][family] for family in families) for k in added} == dict.fromkeys(added, trajectories)
    assert with_p0["surrogate"]["training_sources"] == alone["surrogate"]["training_sources"] + \
        ["rve_paths:p040", "rve_paths:p200", "rve_paths:p400"]
    assert with_p0["surrogate"]["history_variables"] == alone["surrogate"]["history_variables"] + ["p0"]
    changed = {line.split(":")[0].split(".")[0] for line in differences(alone, with_p0)}
    assert changed == {"output_dir", "rve_paths", "surrogate"}
