"""The SLURM executor profile at paper scale, dry-run only: there is no cluster here, so this
checks what can be checked without one — the profile parses, the executor plugin loads, the
paper-scale DAG builds for both references, and the profile's per-rule resources are applied."""

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = str(Path(sys.executable).with_name("snakemake"))
PROFILE = "workflow/profiles/slurm"


def dry_run(tmp_path, *config):
    command = [SNAKEMAKE, "-n", "--profile", PROFILE, "--configfile", "config/paper.yaml",
               "--config", f"output_dir={tmp_path / 'paper'}", *config, "--", "all"]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    return result, result.stdout + result.stderr


@pytest.mark.slow
@pytest.mark.parametrize("reference", ["dem", "elastoplastic"])
def test_slurm_profile_dry_run_builds_the_paper_dag(tmp_path, reference):
    """Pass criterion: `snakemake -n --profile workflow/profiles/slurm --configfile
    config/paper.yaml ... all` exits 0 without sinfo/sbatch, lists the reference runs of both
    paths and the FEM–ML runs, and writes nothing into output_dir."""
    result, output = dry_run(tmp_path, f"reference_material={reference}")
    assert result.returncode == 0, output[-3000:]
    # the cluster profile, and the workflow's own default profile (profiles/default: rerun-incomplete)
    assert f"Using profiles {PROFILE} and workflow specific profile profiles/default" in output
    reference_rule = "fem_dem" if reference == "dem" else "fem_elastoplastic"
    assert f"{tmp_path}/paper/{reference_rule}/path1.h5" in output
    assert f"{tmp_path}/paper/{reference_rule}/path2.h5" in output
    assert f"{tmp_path}/paper/fem_ml/" in output
    if reference == "dem":
        assert "rve" in output
    assert not (tmp_path / "paper").exists()


def test_slurm_profile_names_resources_for_the_heavy_rules():
    """Pass criterion: the profile selects the slurm executor and gives the FEM–DEM rule its
    own runtime, memory and cores (the default 2 h / 8 GB would not hold a paper-scale run)."""
    profile = yaml.safe_load((ROOT / PROFILE / "config.yaml").read_text())
    assert profile["executor"] == "slurm"
    fem_dem = profile["set-resources"]["fem_dem"]
    assert fem_dem["runtime"] > profile["default-resources"]["runtime"]
    assert fem_dem["mem_mb"] > profile["default-resources"]["mem_mb"]
    assert fem_dem["cpus_per_task"] == profile["set-threads"]["fem_dem"]
