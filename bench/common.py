"""What every bench shares: the record it writes, and the machine it was measured on.

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
import subprocess
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
