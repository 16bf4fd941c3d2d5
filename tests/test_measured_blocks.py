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
    with pytest.raises(SystemExit, match="'kernel' is not key=value"):
        common.parse_variant("correction=none,kernel")
