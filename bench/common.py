"""What the benches share: the record each writes and the machine it was measured on, the
adaptive variants of the command line, and the networks the FEM benches use.

A bench starts a :class:`Measurement` before it measures and finishes it after. The record,
one JSON file, holds the commit, the machine (CPU model, cores, memory, load average before
and after), the date, the settings that differ from the defaults, and the figures:

    measurement = Measurement("footing_domain", settings={"path": PATH})
    ...  # measure
    measurement.finish(rows, args.out)

The benches are scripts run from the repository root (``python bench/<name>.py``), so Python
finds this module beside them."""

from __future__ import annotations

import json
import os
import platform
import re
import subprocess
import tempfile
import time
from pathlib import Path

from granular_multiscale.analysis.tables import machine_description

ROOT = Path(__file__).resolve().parents[1]


def commit(repository: Path = ROOT) -> str:
    """The commit measured, with ``+changes`` when the working tree differs from it."""
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=repository, capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=repository,
                           capture_output=True, text=True).stdout.strip()
    return f"{head}+changes" if dirty else head


def config_difference(config: dict, defaults: dict) -> dict:
    """The keys of ``config`` whose values differ from ``defaults`` (nested, as in the config)."""
    difference = {}
    for key, value in config.items():
        default = defaults.get(key) if isinstance(defaults, dict) else None
        if isinstance(value, dict) and isinstance(default, dict):
            inner = config_difference(value, default)
            if inner:
                difference[key] = inner
        elif value != default:
            difference[key] = value
    return difference


class Measurement:
    """One bench's measurement: the machine and its load before, and after, the work."""

    def __init__(self, bench: str, settings: dict | None = None, repository: Path = ROOT):
        self.bench, self.settings, self.repository = bench, dict(settings or {}), repository
        self.started = time.strftime("%Y-%m-%d %H:%M %Z")
        self.load_before = os.getloadavg()
        self.clock = time.perf_counter()

    def record(self, figures) -> dict:
        return {"bench": self.bench, "commit": commit(self.repository), "date": self.started,
                "machine": {**machine_description(), "python": platform.python_version(),
                            "load_average_before": [round(v, 2) for v in self.load_before],
                            "load_average_after": [round(v, 2) for v in os.getloadavg()]},
                "wall_s": round(time.perf_counter() - self.clock, 1),
                "settings": self.settings, "figures": figures}

    def finish(self, figures, out: str | Path) -> dict:
        """Write the record (whole or not at all) to ``out`` and return it."""
        record = self.record(figures)
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(f".{out.name}.tmp")
        tmp.write_text(json.dumps(record, indent=1, default=float) + "\n")
        os.replace(tmp, out)  # a reader never sees half a record
        return record


# --------------------------------------------------------------------------------------
# adaptive variants, written 'key=value,key=value' on the command line


def parse_variant(text: str) -> dict:
    """'anchor_fraction=0.1,correction=kernel,threshold=inf,anchor_seed=3' -> {key: value}: integers,
    numbers (inf, .inf) and strings."""
    out = {}
    for item in filter(None, text.split(",")):
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"variant item {item!r} is not key=value")
        value = value.strip()
        try:
            out[key.strip()] = int(value)  # anchor_seed
        except ValueError:
            try:
                out[key.strip()] = float(value.replace(".inf", "inf"))  # 0.1, inf, .inf
            except ValueError:
                out[key.strip()] = value
    out.setdefault("threshold", float("inf"))
    return out


def variant_name(variant: dict) -> str:
    return re.sub(r"[^A-Za-z0-9_.,=-]+", "_", ",".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}"
                                                     for k, v in sorted(variant.items())))


# --------------------------------------------------------------------------------------
# networks for the FEM benches: the pipeline's, or trained here on the elastoplastic reference


def train_elastoplastic_models(config, elements, folder: Path, logger=None, **settings) -> tuple[Path, Path]:
    """NNσ and ND trained on the elastoplastic reference run of the training path on a mesh of
    `elements` (the config's specimen otherwise), with the config's surrogate settings
    overridden by `settings`; returns the two model files written to `folder`."""
    from granular_multiscale.fem.triaxial import TriaxialProblem
    from granular_multiscale.materials import Elastoplastic
    from granular_multiscale.paths import load_paths_from_config
    from granular_multiscale.surrogate.dataset import build_dataset
    from granular_multiscale.surrogate.training import train

    source = TriaxialProblem.from_config(dict(config, specimen=dict(config["specimen"], elements=list(elements))))
    reference = source.run(Elastoplastic(source.n_gauss_points, initial_stress=source.initial_stress),
                           load_paths_from_config(config)[config["training_path"]], progress=False)
    train_ds, heldout_ds = build_dataset(reference, config["surrogate"]["train_fraction"], config["seed"],
                                         split=config["surrogate"]["split"])
    files = []
    for kind in ("sigma", "tangent"):
        model, _, _ = train(train_ds, heldout_ds, kind, dict(config["surrogate"], **settings), config["seed"],
                            config=config, logger=logger)
        files.append(Path(folder) / f"nn_{kind}.pt")
        model.save(files[-1])
    return files[0], files[1]


def surrogate_models(config, models_dir, problem, logger):
    """The pipeline's networks in `models_dir`, or (without it) networks trained here briefly on the
    elastoplastic reference; returns the two model files and a note saying which."""
    if models_dir:
        folder = Path(models_dir)
        return folder / "nn_sigma.pt", folder / "nn_tangent.pt", f"pipeline models in {folder}"
    # at least 2×2 elements across: one element across keeps ε12 at round-off, which the
    # networks' min–max scaling would turn into noise
    elements = tuple(max(n, m) for n, m in zip(problem.elements, (2, 2, 4)))
    t0 = time.perf_counter()
    sigma, tangent = train_elastoplastic_models(config, elements, Path(tempfile.mkdtemp(prefix="bench_models_")),
                                                logger, epochs=150, learning_rate=5e-3, batch_size=256)
    return (sigma, tangent,
            f"trained here on the elastoplastic {config['training_path']} at {'x'.join(map(str, elements))} "
            f"({time.perf_counter() - t0:.0f} s, 150 epochs)")
