"""What the benches share: one command line, the config and the record each writes, the
machine it was measured on, the networks the FEM benches use, the top-force error, and the
adaptive variants of the command line.

A bench builds its command line with :func:`bench_parser` (``--configfile`` and ``--out`` for every
bench, its own options after), starts a :class:`Measurement` before it measures and finishes it
after. The record, one JSON file (by default ``{output_dir}/bench/<name>.json``,
``plan.Layout.bench``), holds the commit, the machine (CPU model, cores, memory, load average
before and after), the date, the settings that differ from the defaults, and the figures:

    parser = bench_parser("footing_domain", __doc__)
    args = parser.parse_args()                       # args.config: the loaded config; args.out: the record
    measurement = parser.measurement(args, path=PATH)
    ...  # measure
    measurement.finish(rows, args.out)

The benches are scripts run from the repository root (``python bench/<name>.py``), so Python
finds this module beside them."""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from granular_multiscale.analysis.metrics import curve_errors
from granular_multiscale.analysis.tables import machine_description
from granular_multiscale.config import CONFIG_DIR, load_config
from granular_multiscale.plan import Layout

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


def _json_value(value):
    """What json cannot write by itself: numpy scalars and arrays, paths."""
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    return float(value)


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
        tmp.write_text(json.dumps(record, indent=1, default=_json_value) + "\n")
        os.replace(tmp, out)  # a reader never sees half a record
        return record


# --------------------------------------------------------------------------------------
# the command line and the config


def bench_config(configfile=None, overrides: dict | None = None) -> dict:
    """The config a bench runs with: config/config.yaml with the --configfile files merged over it
    in order, as Snakemake merges them over the Snakefile's config, then `overrides` (dotted keys)."""
    return load_config([CONFIG_DIR / "config.yaml", *(configfile or [])], overrides)


class BenchParser(argparse.ArgumentParser):
    """The command line of one bench: ``--configfile`` and ``--out``, then the bench's own options.
    ``parse_args`` loads the config (``args.config``) and, without ``--out``, puts the record where
    the plan's layout puts a bench record of that config (``args.out``)."""

    def __init__(self, name: str, doc: str, configfile: list[str] | None = None, out: Path | None = None):
        super().__init__(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
        self.bench = name
        self.add_argument("--configfile", nargs="+", default=configfile, metavar="FILE",
                          help="config files merged over config/config.yaml in order, as Snakemake's --configfile "
                               f"(default: {' '.join(configfile) if configfile else 'none, config/config.yaml alone'})")
        self.add_argument("--out", type=Path, default=out, metavar="FILE",
                          help=f"the JSON record (default: {out or f'{{output_dir}}/bench/{name}.json of the config'})")

    def parse_args(self, args=None, namespace=None):
        parsed = super().parse_args(args, namespace)
        parsed.bench = self.bench
        parsed.config = bench_config(parsed.configfile)
        if parsed.out is None:
            parsed.out = Path(Layout(parsed.config["output_dir"]).bench(self.bench))
        return parsed

    def measurement(self, args, **settings) -> Measurement:
        """Start this bench's measurement. Its settings: the options given other than their defaults,
        the keys of the config that differ from config/config.yaml's, and `settings`."""
        options = {key: value for key, value in vars(args).items()
                   if key not in ("bench", "config", "out") and value != self.get_default(key)}
        difference = config_difference(args.config, bench_config())
        return Measurement(self.bench, {**options, **({"config_difference": difference} if difference else {}),
                                        **settings})


def bench_parser(name: str, doc: str, configfile: list[str] | None = None, out: Path | None = None) -> BenchParser:
    """The command line of the bench `name` (the name of its record), described by its docstring `doc`;
    `configfile`: the config files it runs with by default (config/config.yaml alone without);
    `out`: its record by default, for a record kept outside the output_dir."""
    return BenchParser(name, doc, configfile, out)


def run_folder(args) -> Path:
    """Where a bench keeps the run files it writes (and reuses), beside its record."""
    return args.out.parent / f"{args.bench}_runs"


def require_files(*files, hint: str) -> None:
    """Stop the bench, naming the first input file that is missing and what makes it."""
    for file in files:
        if not Path(file).is_file():
            raise SystemExit(f"{file} not found: {hint}")


# --------------------------------------------------------------------------------------
# how far a run is from a reference


def curve_error_pct(reference, run, quantity: str = "top_force") -> dict[str, float]:
    """Per load phase ('all' first, then loading, unloading, reloading): the max over the steps of
    |`quantity` − reference's|, in % of the reference's peak magnitude (``analysis.metrics.curve_errors``;
    a run that stopped early, attribute completed = 0, over the steps it reached). Only the load
    curves are compared: a global quantity compares across meshes too (a quarter model
    or one RVE against the full specimen), which the Gauss-point check of curve_errors would refuse."""
    curves = [ds[[name for name in ds.data_vars if set(ds[name].dims) <= {"step"}]] for ds in (reference, run)]
    errors = curve_errors(*curves).query("quantity == @quantity")
    return dict(zip(errors["phase"], errors["max_error_percent_of_peak"].astype(float)))


def top_force_error_pct(reference, run, phase: str = "all") -> float:
    """Max over the path (or over one load phase) of |top force − reference's|, in % of the
    reference's peak top force."""
    return curve_error_pct(reference, run, "top_force")[phase]


def driven_response(model_file, strain: np.ndarray, confining_pressure: float) -> tuple[np.ndarray, np.ndarray]:
    """The networks of `model_file` along the strain histories [steps, points, 6], each step committed
    as converged (no FEM: the material's error alone): their stress [steps, points, 6] (Pa) and
    relative ensemble spread [steps, points] (what FEM–ML writes as ``stress_spread_relative``)."""
    from granular_multiscale.surrogate.material import SurrogateMaterial, relative_spread
    from granular_multiscale.surrogate.synthetic import material_point_run

    material = SurrogateMaterial.from_files(strain.shape[1], model_file, tangent="autodiff")
    stress = material_point_run(material, strain)["stress"].values
    return stress, relative_spread(material.stress_spread, stress, confining_pressure)


# --------------------------------------------------------------------------------------
# adaptive variants, written 'key=value,key=value' on the command line


def parse_variant(text: str) -> dict:
    """'anchor_fraction=0.1,correction=kernel,threshold=inf,anchor_seed=3' -> {key: value}: integers,
    numbers (inf, .inf), true / false and strings."""
    out = {}
    for item in filter(None, text.split(",")):
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"variant item {item!r} is not key=value")
        value = value.strip()
        if value.lower() in ("true", "false"):  # correction_tangent
            out[key.strip()] = value.lower() == "true"
            continue
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

NETWORKS = ("sigma", "tangent")  # NNσ and ND, the networks rule fem_ml puts at the Gauss points


def pipeline_models(config: dict, folder: str | Path | None = None) -> tuple[Path, Path]:
    """The pipeline's NNσ and ND: the files the plan's layout names under the config's output_dir,
    or those of the same names in `folder` (the models folder of another run)."""
    files = [Path(Layout(config["output_dir"]).model(network)) for network in NETWORKS]
    if folder is not None:
        files = [Path(folder) / file.name for file in files]
    return files[0], files[1]


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
    files = dict(zip(NETWORKS, pipeline_models(config, folder)))
    for kind, file in files.items():
        model, _, _ = train(train_ds, heldout_ds, kind, dict(config["surrogate"], **settings), config["seed"],
                            config=config, logger=logger)
        model.save(file)
    return files["sigma"], files["tangent"]


def surrogate_models(config, models_dir, problem, logger):
    """The pipeline's networks in `models_dir`, or (without it) networks trained here briefly on the
    elastoplastic reference; returns the two model files and a note saying which."""
    if models_dir:
        sigma, tangent = pipeline_models(config, models_dir)
        require_files(sigma, tangent, hint="pass the models folder of a finished run")
        return sigma, tangent, f"pipeline models in {models_dir}"
    # at least 2×2 elements across: one element across keeps ε12 at round-off, which the
    # networks' min–max scaling would turn into noise
    elements = tuple(max(n, m) for n, m in zip(problem.elements, (2, 2, 4)))
    t0 = time.perf_counter()
    sigma, tangent = train_elastoplastic_models(config, elements, Path(tempfile.mkdtemp(prefix="bench_models_")),
                                                logger, epochs=150, learning_rate=5e-3, batch_size=256)
    return (sigma, tangent,
            f"trained here on the elastoplastic {config['training_path']} at {'x'.join(map(str, elements))} "
            f"({time.perf_counter() - t0:.0f} s, 150 epochs)")
