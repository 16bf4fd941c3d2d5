"""The measured numbers of the README and docs are rendered from bench records: the blocks in
the repository equal what their records give, a number edited by hand is caught, and a bench
record holds the commit, machine, load, date and settings beside its figures."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))  # the benches are scripts; their shared module sits beside them

import common  # noqa: E402
import update_docs  # noqa: E402

RECORD = ROOT / "docs" / "measured" / "all_default.json"


def test_every_measured_block_equals_its_record():
    result = subprocess.run([sys.executable, str(ROOT / "bench" / "update_docs.py"), "--check"],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    readme = (ROOT / "README.md").read_text()
    assert "<!-- measured: docs/measured/all_default.json headline -->" in readme


def test_a_number_edited_by_hand_is_caught():
    record = json.loads(RECORD.read_text())
    readme = (ROOT / "README.md").read_text()
    block = update_docs.render_headline(record)
    assert block in readme
    speedup = f"**{record['figures']['headline']['speedup']:.0f}×**"
    assert speedup in block
    edited = readme.replace(speedup, "**9999×**")
    assert update_docs.rewrite(edited, "README.md") == readme  # the check would rewrite it back


def test_the_headline_rows_come_from_the_record():
    record = json.loads(RECORD.read_text())
    h = record["figures"]["headline"]
    block = update_docs.render_headline(record)
    assert f"**{h['top_force_max_rel_pct']:.2f} %**" in block
    assert f"{record['figures']['all_wall_s'] / 60:.1f} min" in block
    assert f"Path2 {record['figures']['rules_wall_s']['fem_dem/path2']:.0f} s" in block
    changed = json.loads(json.dumps(record))
    changed["figures"]["headline"]["top_force_max_rel_pct"] = 12.345
    assert "**12.35 %**" in update_docs.render_headline(changed)


def test_a_record_names_what_it_measured(tmp_path):
    measurement = common.Measurement("unit", {"dem": {"n_spheres": 100}})
    record = measurement.finish({"seconds": 1.5}, tmp_path / "unit.json")
    again = json.loads((tmp_path / "unit.json").read_text())
    assert again == json.loads(json.dumps(record))
    assert len(again["commit"].split("+")[0]) == 40 and again["date"][:2] == "20"
    assert again["machine"]["cores"] >= 1 and len(again["machine"]["load_average_before"]) == 3
    assert again["settings"] == {"dem": {"n_spheres": 100}} and again["figures"] == {"seconds": 1.5}
    assert not list(tmp_path.glob(".*.tmp"))  # written whole: no temporary file left


def test_config_difference_keeps_only_what_differs():
    defaults = {"dem": {"n_spheres": 400, "friction": 0.5}, "seed": 0, "paths": ["path1"]}
    config = {"dem": {"n_spheres": 100, "friction": 0.5}, "seed": 0, "paths": ["path1", "path2"]}
    assert common.config_difference(config, defaults) == {"dem": {"n_spheres": 100}, "paths": ["path1", "path2"]}
    assert common.config_difference(defaults, defaults) == {}


def test_a_block_with_an_unknown_renderer_is_named():
    text = "<!-- measured: docs/measured/all_default.json nonsense -->\nx\n<!-- end measured -->"
    with pytest.raises(ValueError, match="unknown renderer 'nonsense'"):
        update_docs.rewrite(text, "README.md")


def test_adaptive_variants_of_the_command_line():
    variant = common.parse_variant("anchor_fraction=0.1,correction=kernel,anchor_seed=3,threshold=.inf")
    assert variant == {"anchor_fraction": 0.1, "correction": "kernel", "anchor_seed": 3, "threshold": float("inf")}
    assert common.variant_name({"threshold": 0.02, "correction": "kernel"}) == "correction=kernel,threshold=0.02"
    assert common.parse_variant("correction_tangent=false") == {"correction_tangent": False, "threshold": float("inf")}
    with pytest.raises(SystemExit, match="'kernel' is not key=value"):
        common.parse_variant("correction=none,kernel")


def with_dem_work(record: dict) -> dict:
    """The record with the DEM work and RVE-path sets that bench_all records (made up here: the
    renderers' arithmetic is what is tested)."""
    record = json.loads(json.dumps(record))
    record["figures"]["dem_work"] = {
        "fem_dem/path1": {"particle_steps": 1_000_000_000, "cpu_s": 900.0, "wall_s": 500.0},
        "fem_dem/path2": {"particle_steps": 800_000_000, "cpu_s": 700.0, "wall_s": 400.0},
        "rve_paths/designed": {"particle_steps": 400_000_000, "cpu_s": 300.0, "wall_s": 200.0}}
    record["figures"]["rve_paths"] = {"designed": {
        "trajectories": 96, "steps": 80, "evaluations": 7680, "lost_contact": 0, "families": {"triaxial": 96},
        "largest_axial_strain_pct": 5.0, "largest_lateral_strain_pct": 3.5, "largest_shear_strain_pct": 6.0}}
    return record


def test_the_dem_cost_and_the_rve_path_sets_come_from_the_run_files():
    record = with_dem_work(json.loads(RECORD.read_text()))
    headline = update_docs.render_headline(record)
    assert "0.86 µs of CPU per particle-step" in headline  # 1900 s / 2.2e9
    h = record["figures"]["headline"]
    paper = 800_000_000 / (h["material_points_evaluated"] * h["n_spheres"]) * 2000 * 1000
    assert f"{paper:.1e} particle-steps, about {paper * 1900 / 2.2e9 / 3600:.0f} CPU-hours" in headline
    sets = update_docs.render_rve_paths(record)
    assert "| `designed` | 96 triaxial × 80 steps | 7680 | 4.00e+08 |" in sets and "| 5.0 % / 3.5 % | 6.0 % | 0 |" in sets
    assert "Together 4.00e+08 particle-steps, 40 % of FEM–DEM Path1's." in sets


def test_the_problem_references_come_from_the_run_tables():
    record = json.loads(RECORD.read_text())
    block = update_docs.render_problem_references(record)
    band = update_docs.pick(update_docs.rows_of(record, "biaxial_bands.csv"), run="biaxial")
    footing = update_docs.pick(update_docs.rows_of(record, "footing.csv"), run="footing")
    assert f"{band['inclination to σ3 (deg)']:.1f}° to σ3" in block
    assert f"{footing['largest pressure (kPa)']:.0f} kPa" in block
