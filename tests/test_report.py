"""The workflow at the tiny scale, on the elastoplastic reference and on FEM–DEM with real
YADE RVEs, then the HTML report: Snakemake must build every figure and table from scratch, and
`snakemake --report` must put each of them, with its caption, and the headline numbers into one
self-contained file. A FEM–ML run that stops early (it may on the tiny scale's noisy 150-sphere
DEM data) must still reach the report, labelled as such."""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from granular_multiscale.data import read_run

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]

FIGURES = [
    "error_map.png",
    "stress_strain_corner.png",
    "stress_strain_centre.png",
    "stress_strain_surface.png",
    "top_force_volumetric_strain.png",
    "fields_axial_displacement.png",
    "fields_shear_strain.png",
    "fields_sigma23.png",
    "training_curves.png",
    "speed_vs_error.png",
]
TABLES = ["speedup.csv", "speedup.html", "accuracy.csv", "accuracy.html"]


def snakemake(*args, cwd=ROOT):
    result = subprocess.run([*SNAKEMAKE, *args], cwd=cwd, capture_output=True, text=True)
    assert result.returncode == 0, f"snakemake {' '.join(args)} failed:\n{result.stdout[-3000:]}\n{result.stderr[-6000:]}"
    return result


@pytest.mark.slow
@pytest.mark.parametrize("reference", ["elastoplastic", "dem"])
def test_tiny_pipeline_builds_the_report(tmp_path, reference):
    out = tmp_path / "tiny"
    override = tmp_path / "override.yaml"
    override.write_text(yaml.safe_dump({
        "output_dir": str(out),
        "reference_material": reference,
    }))  # training epochs as config/tiny.yaml sets them
    config_args = ["--configfile", "config/tiny.yaml", str(override)]
    # what the report needs (rule all adds the FEM–ML runs of the training path and the
    # surrogate stage's own metric tables, which its tests cover)
    targets = [f"{out}/figures/{name}" for name in FIGURES] + [f"{out}/tables/{name}" for name in TABLES]
    targets += [f"{out}/tables/headline.json", f"{out}/vtk/reference/path2", f"{out}/vtk/fem_ml/path2"]
    snakemake("-j2", *config_args, "--", *targets)
    for name in FIGURES:
        assert (out / "figures" / name).stat().st_size > 10_000, name
    for name in TABLES:
        assert (out / "tables" / name).is_file(), name
    fem_ml = read_run(out / "fem_ml" / "path2.h5")
    vtk = out / "vtk" / "fem_ml" / "path2"
    assert (vtk / "path2.pvd").is_file() and len(list(vtk.glob("path2_*.vtu"))) == fem_ml.sizes["step"]
    if fem_ml.attrs["completed"]:
        assert fem_ml.sizes["step"] == 58

    report = out / "report.html"
    snakemake("--report", str(report), *config_args)
    html = report.read_text()
    assert report.stat().st_size > 500_000  # the PNGs are embedded, not linked
    for name in FIGURES + TABLES:
        assert f'"name": "{name}"' in html, f"{name} missing from the report"
    assert html.count("data:image/png") >= len(FIGURES)
    # every result has its caption, every category shows up
    results = json.loads(re.search(r"var results = (\{.*?\});\n", html).group(1))
    for path, entry in results.items():
        assert "What to look for" in entry["caption"] or Path(path).suffix == ".csv", path
    for category in ("1 Gauss points", "2 Specimen", "3 Speed and accuracy", "4 Training"):
        assert category in html
    # the front page states scale, reference material, machine and the headline numbers
    headline = json.loads((out / "tables" / "headline.json").read_text())
    description = re.search(r"var workflow_desc = (\".*?\");\n", html).group(1)
    description = json.loads(description)
    if reference == "elastoplastic":
        assert "Analytic elastoplastic model" in description and "not FEM–DEM" in description
    else:
        assert "YADE RVEs of 150 spheres" in description and "Analytic" not in description
        assert (out / "fem_dem" / "path1.h5").is_file() and (out / "rve" / "summary.json").is_file()
    if not fem_ml.attrs["completed"]:
        assert f"stopped after load step {fem_ml.sizes['step'] - 1} of" in description
    assert "16 Gauss points" in description
    assert f"Measured on {headline['machine']['cores']} cores" in description
    assert f"Speedup {headline['speedup']:.3g}×" in description
    assert f"Held-out stress MAE {headline['stress_mae_heldout_kpa']:.3g} kPa" in description
    assert "System Message" not in description  # reStructuredText rendered without errors
