"""Whether the strip footing's domain is large enough, measured on the analytic elastoplastic
model (no YADE, seconds): the default domain (5 B wide for the half, 3 B deep, 4 × 3 elements)
against one 1.5 times wider, one 1.5 times deeper, both, and twice as large (one more graded
element per direction and step), and against the default domain meshed twice as finely, each with
and without softening.

    .venv/bin/python bench/bench_footing_domain.py [--out results/bench/footing_domain.json]

Printed and written (the record, --out, default {output_dir}/bench/footing_domain.json; the runs
in footing_domain_runs/ beside it) per material and domain: the footing pressure at s/B = 5 % and
10 % and its ratio to the default domain's. The refined mesh separates what the domain does from
what the mesh does.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import pandas as pd

from granular_multiscale.config import load_config
from granular_multiscale.drivers.reference import run_fem_reference
from granular_multiscale.materials.elastoplastic import SOFTENING

from common import bench_parser, run_folder
# (domain [half width, depth] in m, elements [x, z]): the default first
DOMAINS = [([0.5, 0.3], [4, 3]), ([0.75, 0.3], [5, 3]), ([0.5, 0.45], [4, 4]), ([0.75, 0.45], [5, 4]),
           ([1.0, 0.6], [6, 5]), ([0.5, 0.3], [8, 6])]
PATH = [[20, 0.1]]


def run(softening: bool, domain: list, elements: list, out_dir: Path) -> dict:
    overrides = {"reference_material": "elastoplastic", "footing.domain": domain, "footing.elements": elements,
                 "footing.load_paths": {"f": {"segments": PATH}}}
    if softening:
        overrides.update({f"elastoplastic.{k}": v for k, v in SOFTENING.items()})
    config = load_config(overrides=overrides)
    t0 = time.perf_counter()
    name = f"{'softening' if softening else 'plain'}_{domain[0]}x{domain[1]}_{elements[0]}x{elements[1]}.h5"
    ds = run_fem_reference(config, "f", out_dir / name, problem="footing")
    q = ds["footing_pressure"].values
    return {"material": "softening" if softening else "elastoplastic", "domain_m": domain, "elements": elements,
            "pressure_5pct_kPa": 1e-3 * float(q[len(q) // 2]), "pressure_10pct_kPa": 1e-3 * float(q[-1]),
            "wall_s": time.perf_counter() - t0}


def main(argv=None) -> None:
    parser = bench_parser("footing_domain", __doc__)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    measurement = parser.measurement(args, softening=SOFTENING, path=PATH)
    runs_dir = run_folder(args)
    runs_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for softening in (False, True):
        block = [run(softening, domain, elements, runs_dir) for domain, elements in DOMAINS]
        for row in block:
            row["pressure_10pct_over_default"] = row["pressure_10pct_kPa"] / block[0]["pressure_10pct_kPa"]
        rows += block
    print(pd.DataFrame(rows).to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    measurement.finish(rows, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
