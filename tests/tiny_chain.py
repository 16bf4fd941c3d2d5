"""config/tiny.yaml's workflow as the report needs it, built by Snakemake in a test's folder:
its command-line options, its plan and the products the report shows."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import yaml
from dem_fixtures import ROOT

from granular_multiscale.config import load_config
from granular_multiscale.plan import Plan

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
    "calibration.png",
]
TABLES = ["speedup.csv", "speedup.html", "accuracy.csv", "accuracy.html", "surrogate_cost.csv", "surrogate_cost.html",
          "calibration.csv", "calibration.html", "validation_by_phase.csv", "validation_by_phase.html"]


def snakemake(*args, cwd=ROOT):
    result = subprocess.run([*SNAKEMAKE, *args], cwd=cwd, capture_output=True, text=True)
    assert result.returncode == 0, f"snakemake {' '.join(args)} failed:\n{result.stdout[-3000:]}\n{result.stderr[-6000:]}"
    return result


def problem_products(L):
    """The figures and tables of the problems beyond the triaxial specimen, and their VTK folders."""
    items = [L.figure("biaxial/response.png"), L.figure("biaxial/fields_biaxial.png"), L.figure("footing/response.png"),
             L.figure("footing/fields_footing.png"), L.table("biaxial_bands.csv"), L.table("footing.csv"),
             L.table("rve_angles.csv"), L.table("visited_states.csv")]
    for p in ("biaxial", "footing"):
        items += [L.table(f"{p}/surrogate_{p}.csv"), L.figure(f"{p}/surrogate_response_{p}.png"),
                  L.figure(f"{p}/error_map_{p}.png")]
    return items, [L.vtk("biaxial", "biaxial"), L.vtk("footing", "footing")]


@dataclass(frozen=True)
class TinyChain:
    """The chain's output folder, Snakemake's options that select it, and its targets: what the
    report needs, the problems' products where the config keeps the problems (rule all adds the
    FEM–ML runs of the training path and the surrogate stage's own metric tables)."""

    out: Path
    config_args: tuple[str, ...]
    plan: Plan
    targets: tuple[str, ...]
    report: Path

    @classmethod
    def at(cls, folder: Path, reference: str, **settings) -> TinyChain:
        out = folder / "tiny"
        override = folder / "override.yaml"
        override.write_text(yaml.safe_dump({"output_dir": str(out), "reference_material": reference, **settings}))
        plan = Plan(load_config([ROOT / "config/tiny.yaml", override]))  # merged as Snakemake merges them
        L = plan.layout
        targets = [L.figure(name) for name in FIGURES] + [L.table(name) for name in TABLES]
        targets += [L.table("headline.json"), L.vtk("reference", "path2"), L.vtk("fem_ml", "path2")]
        if plan.config["problems"]:
            items, vtk = problem_products(L)
            targets += items + vtk
        return cls(out, ("--configfile", "config/tiny.yaml", str(override)), plan, tuple(map(str, targets)),
                   out / "report.html")
