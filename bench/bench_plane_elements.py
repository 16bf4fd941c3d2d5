"""Which plane-strain element the biaxial test needs, measured on the softening analytic model
(materials/elastoplastic.py SOFTENING, no YADE, seconds): the same specimen, weak zone and load
path on several meshes, with 8-node quadrilaterals at 2 × 2 Gauss points (quad8) and bilinear ones
fully integrated (quad4).

    .venv/bin/python bench/bench_plane_elements.py [--out results/bench/plane_elements.json]

Printed and written (the record, --out, default {output_dir}/bench/plane_elements.json; the runs
in plane_elements_runs/ beside it) per element and mesh: the band metrics (analysis/bands.py), the
peak platen force and the force at the end over the peak, Newton iterations and cutbacks, wall
time. A locking element shows a low band ratio and a band that is not inclined like a shear band;
the rows of one element against each other show the mesh dependence of the post-peak branch.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
import pandas as pd

from granular_multiscale.analysis.bands import band_metrics
from granular_multiscale.config import load_config
from granular_multiscale.drivers.reference import run_fem_reference
from granular_multiscale.materials.elastoplastic import SOFTENING

from common import bench_parser, run_folder
MESHES = [(3, 6), (4, 8), (6, 12), (8, 16)]
ELEMENTS = ("quad8", "quad4")
WEAK_ZONE = {"center": [0.0125, 0.04], "radius": 0.008}


def run(element: str, mesh: tuple[int, int], out_dir: Path) -> dict:
    config = load_config(overrides={"reference_material": "elastoplastic", "biaxial.elements": list(mesh),
                                    "biaxial.element": element, "biaxial.weak_zone": WEAK_ZONE,
                                    **{f"elastoplastic.{k}": v for k, v in SOFTENING.items()}})
    config["newton"]["max_cutbacks"] = 6
    t0 = time.perf_counter()
    ds = run_fem_reference(config, "biaxial", out_dir / f"{element}_{mesh[0]}x{mesh[1]}.h5", problem="biaxial")
    wall = time.perf_counter() - t0
    m = band_metrics(ds)
    force = ds["load_force"].values
    return {
        "element": element, "mesh": f"{mesh[0]}x{mesh[1]}", "gauss_points": m["gauss_points"],
        "peak_force_kN_per_m": 1e-3 * float(force.max()),
        "peak_axial_strain_pct": 100 * float(ds["axial_strain"].values[int(np.argmax(force))]),
        "end_over_peak": float(force[-1] / force.max()),
        "band_ratio": m["band_ratio"], "inclination_deg": m["inclination_deg"], "width_mm": 1e3 * m["width_m"],
        "onset_axial_strain_pct": 100 * m["onset_load"], "max_shear_strain_pct": 100 * m["max_shear_strain"],
        "newton_iterations": int(ds["newton_iterations"].sum()), "cutbacks": int(ds["cutbacks"].sum()),
        "wall_s": wall,
    }


def main(argv=None) -> None:
    parser = bench_parser("plane_elements", __doc__)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    measurement = parser.measurement(args, material=SOFTENING, weak_zone=WEAK_ZONE)
    rows = [run(element, mesh, run_folder(args)) for element in ELEMENTS for mesh in MESHES]
    table = pd.DataFrame(rows)
    print(table.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    measurement.finish(rows, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
