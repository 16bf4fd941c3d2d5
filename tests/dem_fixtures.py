"""Shared helpers of the DEM tests: small consolidated packings, cached for the whole session."""

from __future__ import annotations

import json
from pathlib import Path

import yaml

from granular_multiscale.config import validate_config
from granular_multiscale.dem.rve import RVESpec, prepare_packing

ROOT = Path(__file__).resolve().parents[1]
TEST_SPHERES = 100
SETTINGS = {"strain_rate": 2.5, "min_steps": 20, "max_steps": 20000, "damping": 0.2}


def packing(tmp_path_factory, friction: float = 0.5, n_spheres: int = TEST_SPHERES, seed: int = 0) -> tuple[Path, dict]:
    """A consolidated packing (prepared once per test session) and its summary."""
    root = tmp_path_factory.getbasetemp() / "dem_packings"
    path = root / f"packing_n{n_spheres}_mu{friction}_s{seed}.yade.gz"
    summary_path = path.with_suffix(".json")
    if not path.exists():
        summary = prepare_packing(RVESpec(n_spheres=n_spheres, seed=seed, friction=friction), path)
        summary_path.write_text(json.dumps(summary))
    return path, json.loads(summary_path.read_text())


def tiny_config(output_dir: Path, segments: dict[str, list], **dem) -> dict:
    """config/tiny.yaml with short load paths and small RVEs."""
    config = yaml.safe_load((ROOT / "config" / "tiny.yaml").read_text())
    config["output_dir"] = str(output_dir)
    config["load_paths"] = {name: {"segments": seg} for name, seg in segments.items()}
    names = list(segments)
    config["training_path"], config["validation_path"] = names[0], names[-1]
    # tiny.yaml's names path1 and the RVE-path sets: the tests may replace both
    config.setdefault("surrogate", {}).update(training_sources=[names[0]], weak_zone_sources=[])
    config.setdefault("dem", {}).update({"n_spheres": TEST_SPHERES, **dem})
    return validate_config(config)
