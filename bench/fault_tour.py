"""A tour of faults and bad input at the tiny scale, as a new user would meet them: corrupt,
truncated and deleted files of each kind the pipeline reads back, non-finite and unphysical
config values, bad output directories, broken config files, locks left behind or held, a kill
-9 in the middle of a run, a load step too large to converge.

For each fault: the first line the user reads on the terminal about it, the exit status, and
whether the rerun that follows (after the fix the message asks for, if any) gives the numbers of
a clean run bit for bit (timings aside). It prints a Markdown table and writes it, with the
commit, date and machine, to the record (--out, default {output_dir}/bench/fault_tour.json).
About 10 minutes on 2 cores:

    .venv/bin/python bench/fault_tour.py

The tests (tests/test_faults.py, tests/test_config_values.py, tests/test_error_messages.py)
assert one fault of each class; this tour tries many, end to end through the command line.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from granular_multiscale.data import read_run

from common import bench_parser

ROOT = Path(__file__).resolve().parents[1]

SNAKEMAKE = str(Path(sys.executable).with_name("snakemake"))
TINY = str(ROOT / "config" / "tiny.yaml")
# the lines that carry a message for the user, in the order they are looked for
MESSAGE = re.compile(r"(Configuration error|Output directory locked|set aside|is corrupt|taking over|did not converge|"
                     r"Error in rule|error:|Error:|LockException|cannot be locked|Exception|Error|WARNING)")


def first_message(text: str) -> str:
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    for pattern in MESSAGE.pattern.strip("()").split("|"):
        for line in lines:
            if re.search(pattern, line):
                return line[:220]
    return lines[-1][:220] if lines else ""


def snakemake(args, cwd=ROOT, timeout=900, popen=False):
    command = [SNAKEMAKE, *args]
    if popen:
        return subprocess.Popen(command, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                start_new_session=True)
    try:
        result = subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=timeout)
        return result.returncode, result.stdout + result.stderr
    except subprocess.TimeoutExpired as error:
        return "timeout", (error.stdout or b"").decode() + (error.stderr or b"").decode()


def same_numbers(a_file, b_file) -> bool:
    a, b = read_run(a_file), read_run(b_file)
    if set(a.data_vars) != set(b.data_vars):
        return False
    for name in a.data_vars:
        if "time" not in name:
            x, y = a[name].values, b[name].values
            if not np.array_equal(x, y, equal_nan=x.dtype.kind == "f"):
                return False
    return True


def flip(path: Path, offset: int = 12000) -> None:
    with open(path, "r+b") as f:
        f.seek(min(offset, path.stat().st_size - 8))
        f.write(b"\xde\xad\xbe\xef\xde\xad\xbe\xef")


def truncate(path: Path) -> None:
    os.truncate(path, path.stat().st_size // 2)


class Tour:
    def __init__(self, work: Path):
        self.work = work
        self.rows = []

    def add(self, fault, rc, text, rerun_equal, note=""):
        row = {"fault": fault, "exit": rc, "message": first_message(text), "rerun_equals_clean": rerun_equal,
               "note": note}
        self.rows.append(row)
        print(f"[{len(self.rows):2d}] {fault}: exit {rc}; {row['message']}; rerun = clean: {rerun_equal} {note}",
              flush=True)

    def overlay(self, name, settings) -> list[str]:
        f = self.work / f"{name}.yaml"
        f.write_text(yaml.safe_dump(settings) if isinstance(settings, dict) else settings)
        return ["--configfile", TINY, str(f)]


def chain_faults(tour: Tour) -> None:
    """Files of the tiny elastoplastic chain (about 15 s to build): each fault, then the rerun."""
    out = tour.work / "chain"
    options = tour.overlay("chain", {"output_dir": str(out), "reference_material": "elastoplastic"})
    target = out / "fem_ml" / "path2.h5"
    rc, text = snakemake(["-j2", *options, "--", str(target)])
    assert rc == 0, text[-3000:]
    clean = tour.work / "clean.h5"
    shutil.copy(target, clean)

    def rerun():
        rc, text = snakemake(["-j2", *options, "--", str(target)])
        return rc, text, rc == 0 and same_numbers(clean, target)

    file_faults = [
        ("flip 8 bytes in models/nn_sigma.pt", "models/nn_sigma.pt", flip),
        ("truncate models/nn_sigma.pt", "models/nn_sigma.pt", truncate),
        ("flip 8 bytes in dataset/train.h5", "dataset/train.h5", flip),
        ("delete models/nn_sigma.pt", "models/nn_sigma.pt", Path.unlink),
        ("truncate dataset/train.h5", "dataset/train.h5", truncate),
        ("flip 8 bytes in dataset/heldout.h5", "dataset/heldout.h5", flip),
        ("flip 8 bytes in fem_elastoplastic/path1.h5", "fem_elastoplastic/path1.h5", flip),
        ("truncate fem_elastoplastic/path2.h5", "fem_elastoplastic/path2.h5", truncate),
        ("empty rve_paths/designed.h5", "rve_paths/designed.h5", lambda p: os.truncate(p, 0)),
        ("damage the checksum file of models/nn_sigma.pt", "models/nn_sigma.pt.sha256",
         lambda p: p.write_text("garbage\n")),
        ("delete the checksum file of dataset/train.h5", "dataset/train.h5.sha256", Path.unlink),
        ("truncate the final output fem_ml/path2.h5", "fem_ml/path2.h5", truncate),
    ]
    for fault, name, damage in file_faults:
        if not (out / name).exists():  # the chain's files depend on its config
            print(f"skipped: {fault} ({name} is not an output of this chain)", flush=True)
            continue
        damage(out / name)
        rc, text, equal = rerun()
        tour.add(fault, rc, text, equal)

    rc, text = snakemake(["-j2", *options, "-R", "fem_ml", "--", str(target)])
    tour.add("rerun the FEM-ML rule by hand (-R fem_ml)", rc, text, rc == 0 and same_numbers(clean, target))

    # the step too large to converge
    huge = tour.overlay("huge", {"output_dir": str(out), "reference_material": "elastoplastic",
                                 "load_paths": {"huge": {"segments": [[1, 0.25]]}},
                                 "training_path": "huge", "validation_path": "huge", "surrogate": {"training_sources": ["huge"]},
                                 "newton": {"max_cutbacks": 0, "max_iterations": 1}})
    rc, text = snakemake(["-j1", *huge, "--", str(out / "fem_elastoplastic" / "huge.h5")])
    made = (out / "fem_elastoplastic" / "huge.h5").exists()
    tour.add("one 25 % axial step, 1 Newton iteration, no cutback", rc, text, None,
             f"run file written: {made}")

    # kill -9 of the workflow while the FEM-ML rule runs, then --unlock and the same command
    log = out / "logs" / "fem_ml"
    shutil.rmtree(out / "fem_ml")
    shutil.rmtree(log)  # its log appears again once the FEM-ML job runs: then the workflow is killed
    proc = snakemake(["-j2", *options, "--", str(target)], popen=True)
    deadline = time.time() + 120
    while time.time() < deadline and not (log.exists() and any(log.iterdir())):
        time.sleep(0.2)
    time.sleep(1.0)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    rc, text = snakemake(["-j2", *options, "--", str(target)])
    unlock_rc, unlock_text = snakemake([*options, "--unlock"])
    rc2, text2, equal = rerun()
    taken_over = [line.strip() for line in text.splitlines() if "taking over" in line]
    tour.add("kill -9 of the workflow during FEM-ML; rerun; --unlock; rerun", f"{rc}, {unlock_rc}, {rc2}",
             taken_over[0] if taken_over else text, equal)
    locks(tour, out, options, target, clean)


def locks(tour: Tour, out: Path, options, target, clean) -> None:
    lock = out / ".workflow.lock"
    host = socket.gethostname()
    sleeper = subprocess.Popen(["sleep", "600"])
    with open(f"/proc/{sleeper.pid}/stat") as f:
        start = f.read().rsplit(")", 1)[1].split()[19]
    cases = [
        ("a stale output lock (its pid is gone)",
         {"pid": 2 ** 22 + 17, "host": host, "process_start": "1", "cwd": "/elsewhere", "started": "2026-01-01 00:00"}),
        ("an output lock held by a live process of this host",
         {"pid": sleeper.pid, "host": host, "process_start": start, "cwd": "/elsewhere", "started": "2026-12-04 00:00"}),
        ("an output lock from another host",
         {"pid": 1, "host": "other-node", "process_start": "1", "cwd": "/elsewhere", "started": "2026-12-04 00:00"}),
        ("an unreadable output lock", "{not json"),
    ]
    for fault, content in cases:
        lock.write_text(content if isinstance(content, str) else json.dumps(content))
        rc, text = snakemake(["-j2", *options, "-f", "--", str(target)])
        equal = rc == 0 and same_numbers(clean, target)
        if rc != 0:
            lock.unlink(missing_ok=True)
            rc2, _ = snakemake(["-j2", *options, "-f", "--", str(target)])
            equal = rc2 == 0 and same_numbers(clean, target)
        tour.add(fault, rc, text, equal, "" if rc == 0 else "rerun after removing the lock")
    sleeper.kill()


def config_faults(tour: Tour) -> None:
    """Bad values: each stops the workflow before any job (a dry run shows it)."""
    base = {"output_dir": str(tour.work / "config_out")}
    values = [
        ("specimen.confining_pressure: 1e999", {"specimen": {"confining_pressure": 1e999}}),
        ("specimen.confining_pressure: .nan", "specimen: {confining_pressure: .nan}\n"),
        ("dem.strain_rate: .inf", "dem: {strain_rate: .inf}\n"),
        ("dem.friction: .nan", "dem: {friction: .nan}\n"),
        ("dem.friction: -0.5", {"dem": {"friction": -0.5}}),
        ("dem.diameter_min: 0.009 (above diameter_max)", {"dem": {"diameter_min": 0.009}}),
        ("dem.density: 0", {"dem": {"density": 0}}),
        ("dem.youngs_modulus: -3e8", {"dem": {"youngs_modulus": -3.0e8}}),
        ("dem.poisson_ratio: 0.7", {"dem": {"poisson_ratio": 0.7}}),
        ("dem.n_spheres: 3", {"dem": {"n_spheres": 3}}),
        ("specimen.elements: [1, 1, 0]", {"specimen": {"elements": [1, 1, 0]}}),
        ("specimen.elements: two (wrong type)", {"specimen": {"elements": "two"}}),
        ("surrogate.learning_rate: -1e-3", {"surrogate": {"learning_rate": -1.0e-3}}),
        ("newton.tolerance: .inf", "newton: {tolerance: .inf}\n"),
        ("an unknown key (specimen.confining_presure)", {"specimen": {"confining_presure": 1.0e5}}),
        ("a load path step count of 0", {"load_paths": {"bad": {"segments": [[0, 0.01]]}}}),
    ]
    for fault, setting in values:
        if isinstance(setting, str):
            text = yaml.safe_dump(base) + setting
            options = tour.overlay("value", text)
        else:
            options = tour.overlay("value", {**base, **setting})
        rc, text = snakemake(["-n", *options])
        tour.add(fault, rc, text, None, "stops before any job")
    for fault, folder in [("output_dir: \"\"", ""), ("output_dir: /", "/"), ("output_dir: . (the repository)", "."),
                          ("output_dir: results/tiny/ (trailing slash)", "results/tiny/")]:
        rc, text = snakemake(["-n", *tour.overlay("dir", {"output_dir": folder})])
        planned = sorted({line.split()[1].split("/")[0] + "/" + line.split()[1].split("/")[1]
                          for line in text.splitlines() if line.strip().startswith("output: results/")})
        tour.add(fault, rc, "" if rc == 0 else text, None, f"accepted: writes under {', '.join(planned)}" if rc == 0 else "")
    rc, text = snakemake(["-n", *tour.overlay("yaml", "specimen: {confining_pressure: [1\n")])
    tour.add("invalid YAML in a --configfile overlay", rc, text, None, "Snakemake's own message")
    rc, text = snakemake(["-n", "--configfile", TINY, str(tour.work / "missing.yaml")])
    tour.add("a missing --configfile", rc, text, None, "Snakemake's own message")
    clone = tour.work / "clone"
    shutil.copytree(ROOT, clone, ignore=shutil.ignore_patterns(".venv", ".git", ".snakemake", "results", "__pycache__"))
    with open(clone / "config" / "config.yaml", "a") as f:
        f.write("specimen: {confining_pressure: [1\n")
    rc, text = snakemake(["-n"], cwd=clone)
    tour.add("invalid YAML in config/config.yaml", rc, text, None)


def dem_faults(tour: Tour) -> None:
    """The packing and a long DEM step."""
    out = tour.work / "dem"
    options = tour.overlay("dem", {"output_dir": str(out), "dem": {"n_spheres": 100}})
    packing = out / "rve" / "packing_0.yade.gz"
    rc, text = snakemake(["-j1", *options, "--", str(packing)])
    assert rc == 0, text[-3000:]
    summary = json.loads((out / "rve" / "summary.json").read_text())["packings"][0]
    truncate(packing)
    rc, text = snakemake(["-j1", *options, "--", str(packing)])
    again = json.loads((out / "rve" / "summary.json").read_text())["packings"][0]
    keys = [k for k in summary if k not in ("wall_time", "particle_step_time", "log")]
    tour.add("truncate rve/packing_0.yade.gz", rc, text, all(summary[k] == again[k] for k in keys),
             "YADE's archive holds its writing time: the consolidated state is compared")
    # one 25 % axial step with DEM: the heartbeat while it runs (stopped after 100 s)
    big = tour.overlay("bigstep", {"output_dir": str(out), "dem": {"n_spheres": 100},
                                   "load_paths": {"big": {"segments": [[1, 0.25]]}},
                                   "training_path": "big", "validation_path": "big", "surrogate": {"training_sources": ["big"]}})
    proc = snakemake(["-j2", *big, "--", str(out / "fem_dem" / "big.h5")], popen=True)
    time.sleep(100)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    logs = list((out / "logs").rglob("big*.log"))
    beats = [line for f in logs for line in f.read_text().splitlines() if "RVEs done" in line or "DEM steps" in line]
    tour.add("one 25 % axial step with DEM (stopped after 100 s)", "killed", beats[-1] if beats else "no heartbeat",
             None, f"{len(beats)} heartbeat lines in {[str(f.relative_to(out)) for f in logs]}")
    snakemake([*big, "--unlock"])


def main(argv=None):
    parser = bench_parser("fault_tour", __doc__)
    args = parser.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="fault_tour."))
    tour = Tour(work)
    measurement = parser.measurement(args)
    started = time.time()
    try:
        config_faults(tour)
        chain_faults(tour)
        dem_faults(tour)
    finally:
        print(f"\n{len(tour.rows)} faults in {time.time() - started:.0f} s\n")
        print("| # | fault | exit | message | rerun = clean |\n|---|---|---|---|---|")
        for i, row in enumerate(tour.rows, 1):
            equal = {True: "yes", False: "NO", None: "–"}[row["rerun_equals_clean"]]
            print(f"| {i} | {row['fault']} | {row['exit']} | {row['message'].replace('|', '/')} | {equal} "
                  f"{row['note']} |")
        measurement.finish(tour.rows, args.out)
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
