"""Shared helpers of the DEM tests: small consolidated packings, cached for the whole session."""

from __future__ import annotations

import json
import os
from pathlib import Path

import yaml
from filelock import FileLock

from granular_multiscale.config import validate_config
from granular_multiscale.dem.rve import RVESpec, prepare_packing

ROOT = Path(__file__).resolve().parents[1]
TEST_SPHERES = 100
SETTINGS = {"strain_rate": 2.5, "min_steps": 20, "max_steps": 20000, "damping": 0.2}


def session_folder(tmp_path_factory, name: str) -> Path:
    """A folder of the whole test session, shared by the workers of `pytest -n` (their base
    folders are siblings in the session's folder): what is built there once, under a FileLock,
    serves every worker."""
    base = tmp_path_factory.getbasetemp()
    folder = (base.parent if "PYTEST_XDIST_WORKER" in os.environ else base) / name
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def packing(tmp_path_factory, friction: float = 0.5, n_spheres: int = TEST_SPHERES, seed: int = 0) -> tuple[Path, dict]:
    """A consolidated packing and its summary, prepared once per test session for all workers."""
    root = session_folder(tmp_path_factory, "dem_packings")
    path = root / f"packing_n{n_spheres}_mu{friction}_s{seed}.yade.gz"
    summary_path = path.with_suffix(".json")
    with FileLock(f"{path}.lock"):  # one worker prepares it, the other waits for the summary
        if not summary_path.exists():
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
