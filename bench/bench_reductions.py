"""What each reduction of the scene costs in accuracy with DEM RVEs, measured side by side on the
validation path with the same packing and the configured FEM–DEM settings:

* quarter symmetry (``specimen.symmetry: quarter``, rough platens) against the full specimen;
* one RVE for a homogeneous field (``specimen.uniform_field: true``) against the full specimen
  with smooth platens (the only scene where a uniform field is valid).

    .venv/bin/python bench/bench_reductions.py                        # tiny scale (~2 min)
    .venv/bin/python bench/bench_reductions.py --configfile config/config.yaml \\
        --full results/fem_dem/path2.h5                               # reuse the pipeline's full run

A DEM packing is not mirror-symmetric, so a quarter model imposes a symmetry the full specimen
does not have; one packing at every Gauss point makes every RVE answer the same strain the
same way, so the question is how far the full specimen's field strays from that symmetry.
Printed per reduction: top force (largest difference in % of the full run's peak), volumetric
strain (in % of its peak magnitude), Gauss-point stress (MAE over steps, points and components,
and in % of the mean stress magnitude) at the same positions, and the DEM particle-steps of each.
For the full run it also prints its own asymmetry: the stress difference between each Gauss point
of the quarter region and its three mirror images. The scale is the config's (--configfile,
default config/tiny.yaml); the rows are written to the record (--out, default
{output_dir}/bench/reductions.json), the runs to ``reductions_runs/`` beside it, and reused.
"""

from __future__ import annotations

import copy
import logging
from pathlib import Path

import numpy as np
import pandas as pd

from granular_multiscale.data import read_run
from granular_multiscale.drivers.fem_dem import run_fem_dem
from granular_multiscale.plan import Layout

from common import bench_parser, curve_error_pct, require_files, run_folder, top_force_error_pct

SCENES = {
    "full_rough": {"platen": "rough", "symmetry": "none", "uniform_field": False},
    "quarter_rough": {"platen": "rough", "symmetry": "quarter", "uniform_field": False},
    "full_smooth": {"platen": "smooth", "symmetry": "none", "uniform_field": False},
    "uniform_smooth": {"platen": "smooth", "symmetry": "none", "uniform_field": True},
}


def match_points(positions: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Index into `positions` of each target position (they must coincide to round-off)."""
    d = np.linalg.norm(positions[None, :, :] - targets[:, None, :], axis=2)
    index = d.argmin(axis=1)
    if d[np.arange(len(targets)), index].max() > 1e-9:
        raise ValueError("Gauss-point positions of the two runs do not coincide")
    return index


def stress_difference(a: np.ndarray, b: np.ndarray) -> dict:
    """MAE (kPa) and MAE in % of the mean stress magnitude, over load steps 1..n."""
    err = np.abs(a[1:] - b[1:])
    scale = np.abs(b[1:, :, :3]).mean()
    return {"stress_mae_kpa": 1e-3 * err.mean(), "stress_mae_pct": 100 * err.mean() / scale}


def curves(run, reference) -> dict:
    """Largest differences of the load curves over the path, in % of the reference's peak magnitude."""
    return {"top_force_max_pct": top_force_error_pct(reference, run),
            "volumetric_strain_max_pct": curve_error_pct(reference, run, "volumetric_strain")["all"]}


def mirror_asymmetry(full, size) -> dict:
    """Stress difference between the full run's quarter-region points and their mirror images."""
    x = full.gp_position.values
    quarter = np.flatnonzero((x[:, 0] > size[0] / 2) & (x[:, 1] > size[1] / 2))
    stress = full.stress.values
    diffs = []
    for flip in ((True, False), (False, True), (True, True)):
        mirrored = x[quarter].copy()
        if flip[0]:
            mirrored[:, 0] = size[0] - mirrored[:, 0]
        if flip[1]:
            mirrored[:, 1] = size[1] - mirrored[:, 1]
        partner = match_points(x, mirrored)
        # the normal components and ε23... change sign with the shear under a mirror: compare the
        # normal stresses, which a mirror leaves unchanged
        diffs.append(np.abs(stress[1:, quarter, :3] - stress[1:, partner, :3]))
    err = np.concatenate(diffs, axis=1)
    return {"stress_mae_kpa": 1e-3 * err.mean(), "stress_mae_pct": 100 * err.mean() / np.abs(stress[1:, :, :3]).mean()}


def main(argv=None) -> list[dict]:
    parser = bench_parser("reductions", __doc__, configfile=["config/tiny.yaml"])
    parser.add_argument("--packing", help="consolidated packing (default: <output_dir>/rve/packing_0.yade.gz)")
    parser.add_argument("--full", help="an existing full, rough-platen FEM–DEM run of the validation path to reuse")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--verbose", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(asctime)s %(message)s")
    logger = logging.getLogger("bench")

    config = args.config
    layout = Layout(config["output_dir"])
    path = config["validation_path"]
    packing = Path(args.packing or layout.packings(1)[0])
    require_files(packing, hint=f"run `snakemake -j2 {layout.packing_summary()}` with the same config first, "
                                "or pass --packing")
    measurement = parser.measurement(args)
    runs, cost = {}, {}
    for name, scene in SCENES.items():
        target = run_folder(args) / name / f"{path}.h5"
        if name == "full_rough" and args.full:
            target = Path(args.full)
        if not target.exists():
            cfg = copy.deepcopy(config)
            cfg["specimen"].update(scene)
            print(f"running {name} ...", flush=True)
            run_fem_dem(cfg, path, [str(packing)], str(target), None, args.workers, logger=logger)
        runs[name] = read_run(target)
        ds = runs[name]
        if ds.attrs["newton_tolerance"] != runs["full_rough"].attrs["newton_tolerance"]:
            raise SystemExit(f"{target}: Newton tolerance {ds.attrs['newton_tolerance']} differs from the full run's")
        cost[name] = float(ds.attrs["dem_particle_steps"])

    size = config["specimen"]["size"]
    full, quarter = runs["full_rough"], runs["quarter_rough"]
    if all(n % 2 == 0 for n in config["specimen"]["elements"][:2]):
        at = match_points(full.gp_position.values, quarter.gp_position.values)
        quarter_stress = stress_difference(quarter.stress.values, full.stress.values[:, at])
    else:  # an odd mesh's quarter has other elements: no Gauss point in common
        quarter_stress = {"stress_mae_kpa": np.nan, "stress_mae_pct": np.nan}
    smooth, uniform = runs["full_smooth"], runs["uniform_smooth"]
    rows = [
        {"reduction": "quarter symmetry (rough platens)", "against": "full specimen, rough",
         **curves(quarter, full), **quarter_stress,
         "rves": quarter.sizes["gp"],
         "particle_steps_ratio": cost["quarter_rough"] / cost["full_rough"]},
        {"reduction": "uniform field, one RVE (smooth platens)", "against": "full specimen, smooth",
         **curves(uniform, smooth), **stress_difference(uniform.stress.values, smooth.stress.values),
         "rves": 1, "particle_steps_ratio": cost["uniform_smooth"] / cost["full_smooth"]},
        {"reduction": "(full, rough: its own mirror asymmetry)", "against": "its mirror images",
         "top_force_max_pct": np.nan, "volumetric_strain_max_pct": np.nan, **mirror_asymmetry(full, size),
         "rves": full.sizes["gp"], "particle_steps_ratio": 1.0},
    ]
    table = pd.DataFrame(rows)
    pd.set_option("display.width", 200)
    print(f"\noutput_dir {config['output_dir']}, {path}, {config['dem']['n_spheres']} spheres per RVE, packing {packing}, "
          f"Newton tolerance {full.attrs['newton_tolerance']:g}")
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    measurement.finish(rows, args.out)
    print(f"\nwrote {args.out}")
    return rows


if __name__ == "__main__":
    main()
