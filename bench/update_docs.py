"""Rewrite the measured blocks of the README and docs from the bench records.

A block sits between two markers naming its record and its renderer:

    <!-- measured: docs/measured/all_default.json headline -->
    ... (generated: do not edit by hand)
    <!-- end measured -->

    python bench/update_docs.py            # rewrite every block
    python bench/update_docs.py --check    # exit 1, naming the block, if one differs from its record

tests/test_measured_blocks.py runs the check, so a number edited by hand, or a record
regenerated without its blocks, fails the suite."""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BLOCK = re.compile(r"(<!-- measured: (\S+) (\w+) -->\n)(.*?)(<!-- end measured -->)", re.S)


def documents() -> list[str]:
    """The README and every page of docs/ (the ones without a block are left alone)."""
    return ["README.md", *sorted(str(path.relative_to(ROOT)) for path in (ROOT / "docs").glob("*.md"))]


def rows_of(record: dict, table: str) -> list[dict]:
    try:
        return record["figures"]["tables"][table]
    except KeyError:
        raise ValueError(f"record of bench {record.get('bench')!r} has no table {table!r}") from None


def pick(rows: list[dict], **match) -> dict:
    found = [r for r in rows if all(r.get(k) == v for k, v in match.items())]
    if len(found) != 1:
        raise ValueError(f"{len(found)} rows match {match}, not one")
    return found[0]


def run_label(record: dict) -> str:
    return f"`all` of {record['date'].split()[0]}"


def adaptive_rows(record: dict) -> list[dict]:
    """The adaptive runs of the validation path in the run's speedup table, with their error."""
    speed, accuracy = rows_of(record, "speedup.csv"), rows_of(record, "accuracy.csv")
    reference = pick(speed, source="this run", method=record["figures"]["headline"]["reference"])
    rows = []
    for row in speed:
        if row["source"] == "this run" and str(row["method"]).startswith("adaptive"):
            error = pick(accuracy, method=row["method"])["top_force_max_rel_pct"]
            rows.append({"method": row["method"], "error": error, "wall_s": row["wall_time_s"],
                         "dem_work": row["dem_particle_steps"] / reference["dem_particle_steps"]})
    return rows


#: the paper's mesh (5 × 5 × 10 hexahedra, 8 Gauss points each) and RVE size
PAPER_RVES, PAPER_SPHERES = 2000, 1000


def dem_work(record: dict) -> dict[str, dict]:
    """The DEM work of every DEM run of the record: particle-steps, CPU and wall seconds (bench_all)."""
    return record["figures"]["dem_work"]


def dem_cost_rows(record: dict) -> list[str]:
    """The DEM cost per particle-step and, at that cost, FEM–DEM of Path2 at the paper scale."""
    work = dem_work(record).values()
    cpu_per_step = sum(w["cpu_s"] for w in work) / sum(w["particle_steps"] for w in work)
    h, cores, label = record["figures"]["headline"], record["machine"]["cores"], run_label(record)
    per_sphere = dem_work(record)["fem_dem/path2"]["particle_steps"] / (h["material_points_evaluated"] * h["n_spheres"])
    paper_steps = per_sphere * PAPER_RVES * PAPER_SPHERES
    hours = paper_steps * cpu_per_step / 3600
    return [f"| DEM cost | {1e6 * cpu_per_step:.2f} µs of CPU per particle-step (all FEM–DEM and RVE-path runs) | "
            f"{label}, the run files |",
            f"| FEM–DEM of Path2 at the paper scale (2000 RVEs × 1000 spheres), estimated | "
            f"{paper_steps:.1e} particle-steps, about {hours:.0f} CPU-hours ({hours / cores:.0f} h on {cores} cores; "
            f"the paper needed 24.8 h) | {label}: the default Path2 run's particle-steps per RVE sphere, scaled, "
            f"at that DEM cost |"]


def render_headline(record: dict) -> str:
    """The rows of the README's headline table measured in one `all` run."""
    f, h = record["figures"], record["figures"]["headline"]
    machine, label = record["machine"], run_label(record)
    rules = f["rules_wall_s"]
    setup = f"set-up {f['setup_s']:.0f} s, " if f.get("setup_s") is not None else ""
    report = f"report {f['report_s']:.0f} s" if f.get("report_s") is not None else ""
    total = sum(v for v in (f["all_wall_s"], f.get("setup_s"), f.get("report_s")) if v is not None)
    note = f", {f['note']}" if f.get("note") else ""
    work = dem_work(record)
    lines = [
        "| quantity | value | from |",
        "| --- | --- | --- |",
        f"| `snakemake -j2 all`, default scale | **{f['all_wall_s'] / 60:.1f} min** ({setup}{report}: "
        f"{total / 60:.0f} min in all) | fresh clone, {label}, {machine['cores']} cores of {machine['cpu']}{note} |",
        f"| FEM–DEM, default scale ({h['gauss_points']} RVEs × {h['n_spheres']} spheres, 2 workers) | "
        f"Path1 {rules['fem_dem/path1']:.0f} s, Path2 {rules['fem_dem/path2']:.0f} s | {label}, its `benchmarks/` files |",
        f"| DEM particle-steps, default scale | Path1 {work['fem_dem/path1']['particle_steps']:.2e}, "
        f"Path2 {work['fem_dem/path2']['particle_steps']:.2e} | {label}, the run files |",
        *dem_cost_rows(record),
        f"| FEM–ML error on Path2 (largest top-force error over the path, % of the peak) | "
        f"**{h['top_force_max_rel_pct']:.2f} %** (no history variables: {h['ablation_top_force_max_rel_pct']:.2f} %) | "
        f"the default networks as trained in {label} |",
        f"| speedup of one FEM–ML answer | **{h['speedup']:.0f}×** (Path2: {h['surrogate_wall_time_s']:.2f} s against "
        f"FEM–DEM's {h['reference_wall_time_s']:.0f} s); making the surrogate took {h['surrogate_cost_s']:.0f} s "
        f"and pays back after {h['break_even_runs']} runs | {label}, side by side |",
    ]
    accuracy = rows_of(record, "accuracy.csv")
    for row in adaptive_rows(record):
        threshold = row["method"].split(", ", 1)[-1]
        controls = [r for r in accuracy if str(r["method"]).startswith("control") and
                    str(r["method"]).endswith(f"threshold {threshold.split()[-1]}")]
        control = "".join(f"; its control (the elastoplastic model at the same DEM points) "
                          f"{r['top_force_max_rel_pct']:.2f} %" for r in controls)
        lines.append(f"| adaptive FEM–DEM–ML, Path2, {threshold} | {row['error']:.2f} % at "
                     f"{100 * row['dem_work']:.1f} % of FEM–DEM's DEM particle-steps, {row['wall_s']:.0f} s{control} "
                     f"| {label} |")
    band = pick(rows_of(record, "biaxial_bands.csv"), run="biaxial")
    lines.append(
        f"| biaxial test ({band['mesh'].replace('x', ' × ')} quad8, {band['Gauss points']} RVEs) | force peak at "
        f"{band['axial strain at peak (%)']:.2f} % axial strain; band onset {band['band onset: axial strain (%)']:.2f} %, "
        f"{band['inclination to σ3 (deg)']:.1f}° to σ3 (Roscoe {band['Roscoe 45+ψ/2 (deg)']:.1f}°); "
        f"FEM–DEM {rules['biaxial/fem_dem/biaxial']:.0f} s | {label} |")
    footing = pick(rows_of(record, "footing.csv"), run="footing")
    lines.append(
        f"| strip footing ({footing['Gauss points']} RVEs) | {footing['largest pressure / q0']:.1f} q0 at "
        f"s/B = {footing['settlement at the end s/B (%)']:.0f} %, still rising "
        f"({footing['pressure gain over the last 20 % of the settlement (%)']:.0f} % over the last fifth); "
        f"FEM–DEM {rules['footing/fem_dem/footing']:.0f} s | {label} |")
    lines += problem_headline_rows(record)
    return "\n".join(lines) + "\n"


def _band(row: dict) -> str:
    """', band inclination +1.2°' against the reference for a row of the biaxial test's table."""
    value = row.get("inclination − reference (deg)")
    return "" if value is None or value != value else f", band {value:+.1f}°"  # NaN: no band


def problem_headline_rows(record: dict) -> list[str]:
    """FEM–ML and the adaptive run beside its control on each problem (the headline's last rows)."""
    label, lines = run_label(record), []
    for problem, title in (("biaxial", "biaxial test"), ("footing", "strip footing")):
        if f"{problem}/surrogate_{problem}.csv" not in record["figures"]["tables"]:
            continue  # a record of a run without the surrogate on the problems
        rows = {r["run"]: r for r in rows_of(record, f"{problem}/surrogate_{problem}.csv")}
        ml = next(r for name, r in rows.items() if name.startswith("FEM–ML"))
        text = (f"FEM–ML {ml['force: largest error (% of peak)']:.1f} % (steps {ml['steps reached']}){_band(ml)}")
        for start, what, has_band in (
                ("FEM–ML solved as the reference", "solved as the reference is (its Newton settings, ND tangent)", True),
                ("FEM–ML's networks along", "its networks along the reference's strains (no FEM)", False)):
            row = next((r for name, r in rows.items() if name.startswith(start)), None)
            if row is not None:  # rows of the runs since 2026-12-07
                text += f"; {what} {row['force: largest error (% of peak)']:.1f} %{_band(row) if has_band else ''}"
        adaptive = [(name, r) for name, r in rows.items() if name.startswith("adaptive")]
        control = [r for name, r in rows.items() if name.startswith("control")]
        if adaptive and control:
            (name, a), c = adaptive[0], control[0]
            share = a["DEM particle-steps (% of the reference's)"]
            text += (f"; {name.removeprefix('adaptive FEM–DEM–ML, ')}: {a['force: largest error (% of peak)']:.1f} % at "
                     f"{share:.0f} % of the DEM work{_band(a)}, its control (elastoplastic model, the same DEM points) "
                     f"{c['force: largest error (% of peak)']:.1f} %{_band(c)}")
        lines.append(f"| the surrogate on the {title} (largest force error over the path, % of the peak) | {text} "
                     f"| {label}, networks that never saw it |")
    return lines


def render_rules(record: dict) -> str:
    """The wall time of every heavy rule of one `all` run (a table)."""
    f, label = record["figures"], run_label(record)
    lines = [f"{label}, commit {record['commit'][:7]}, {record['machine']['cpu']}: `snakemake -j2 all` "
             f"**{f['all_wall_s'] / 60:.1f} minutes** ({f['all_wall_s']:.0f} s). Rules of more than 10 s:", "",
             "| rule (benchmark file) | wall (s) |", "| --- | --- |"]
    for name, seconds in sorted(f["rules_wall_s"].items(), key=lambda item: -item[1]):
        if seconds > 10:
            lines.append(f"| `{name}` | {seconds:.0f} |")
    return "\n".join(lines) + "\n"


def render_fem_ml(record: dict) -> str:
    """FEM–ML by tangent and ablation, and the cheaper FEM–DEM, on the validation path of one run."""
    speed, accuracy = rows_of(record, "speedup.csv"), rows_of(record, "accuracy.csv")
    h = record["figures"]["headline"]
    lines = [f"{run_label(record)}, Path2, against {h['reference']} ({h['reference_wall_time_s']:.0f} s):", "",
             "| run | steps | wall time | speedup | DEM particle-steps, % of FEM–DEM | held-out σ MAE "
             "| top force max / RMS error (% of peak) | vol. strain max error (% points) | Newton corrections per step |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    reference = pick(speed, source="this run", method=h["reference"])
    for row in accuracy:
        timing = pick(speed, source="this run", method=row["method"])
        dem_share = 100 * timing["dem_particle_steps"] / reference["dem_particle_steps"]
        lines.append(
            f"| {row['method']} | {timing['load_steps']}/{h['reference_load_steps']} | "
            f"{timing['wall_time_s']:.2f} s | {timing['speedup']:.0f}× | {dem_share:.1f} % | "
            f"{row['stress_mae_heldout_kpa']:.2f} kPa | "
            f"{row['top_force_max_rel_pct']:.2f} / {row['top_force_rms_rel_pct']:.2f} | "
            f"{row['volumetric_strain_max_abs_pct']:.3f} | {row['newton_per_step']:.2f} |")
    lines += ["", f"Making the surrogate (RVE packings, Path1, the RVE-path sets, dataset, networks) took "
                  f"{h['surrogate_cost_s']:.0f} s; it pays back after {h['break_even_runs']} FEM–ML runs."]
    return "\n".join(lines) + "\n"


def _number(value, digits: int = 2) -> str:
    return "–" if value is None or value != value else f"{value:.{digits}f}"


def problem_table(rows: list[dict], problem: str) -> list[str]:
    """The lines of a problem's surrogate table (``analysis/problem_surrogate.py`` columns), a row
    per run: the problems' runs of `all`, a bench's adaptive variants or other FEM–DEM runs."""
    zone = "in the band" if problem == "biaxial" else "under the footing"
    rest = "outside the band" if problem == "biaxial" else "elsewhere"
    band = problem == "biaxial"
    lines = ["| run | steps | force max error, up to / after the peak (% of peak) | vol. strain max error (% of peak) "
             f"| σ MAE {zone} / {rest} (kPa) |" + (" band inclination, onset (Δ to the reference) |" if band else "")
             + " spread–error ρ, error / spread | DEM particle-steps | DEM points at the end (% " + zone + ") | wall |",
             "| --- | --- | --- | --- | --- |" + (" --- |" if band else "") + " --- | --- | --- | --- |"]
    for row in rows:
        dem_points = row.get("DEM points at the end")
        where = row.get(f"DEM points at the end {zone} (%)")
        line = (f"| {row['run']} | {row['steps reached']} | {_number(row['force: up to the peak (%)'])} / "
                f"{_number(row['force: after the peak (%)'])} | "
                f"{_number(row['volumetric strain: largest error (% of its peak)'], 1)} | "
                f"{_number(row[f'stress MAE {zone} (kPa)'], 1)} / {_number(row[f'stress MAE {rest} (kPa)'], 1)} |")
        if band:
            line += (f" {_number(row['band inclination (deg)'], 1)}° ({row['inclination − reference (deg)']:+.1f}°), "
                     f"{_number(row['band onset: axial strain (%)'])} % ({_number(row['onset − reference (% strain)'])}) |")
        dem = row["DEM particle-steps (% of the reference's)"]
        line += (f" {_number(row.get('spread–error rank correlation (after the peak)'))}, "
                 f"{_number(row.get('median error / spread'))} | "
                 f"{'–' if dem != dem or not dem else f'{dem:.1f} %'} | "
                 f"{'–' if dem_points is None or dem_points != dem_points else f'{dem_points:.0f} ({_number(where, 0)} %)'} | "
                 f"{row['wall time (s)']:.1f} s |")
        lines.append(line)
    return lines


def render_problems(record: dict) -> str:
    """Every method on the biaxial test and the footing against their FEM–DEM runs (one table each)."""
    lines = []
    for problem, title in (("biaxial", "Biaxial test"), ("footing", "Strip footing")):
        if f"{problem}/surrogate_{problem}.csv" not in record["figures"]["tables"]:
            lines += [f"{title}: {run_label(record)} ran no surrogate on this problem.", ""]
            continue
        rows = rows_of(record, f"{problem}/surrogate_{problem}.csv")
        zone = "in the band" if problem == "biaxial" else "under the footing"
        lines += [f"{title}, {run_label(record)}, against {rows[0]['run']} ({rows[0]['wall time (s)']:.0f} s; "
                  f"{rows[0][f'Gauss points {zone}']} of its Gauss points {zone}):", ""]
        lines += problem_table(rows[1:], problem) + [""]
    return "\n".join(lines)


def render_calibration(record: dict) -> str:
    """The ensemble spread's calibration on the validation path and the problems: median error / spread,
    as measured and scaled by the held-out trajectories' scale (tables calibration*, spread_scale)."""
    tables = record["figures"]["tables"]
    scales = {row["networks"]: row for row in tables["spread_scale.csv"]}
    lines = [f"{run_label(record)}. The spread's scale, the median error / spread on the held-out trajectories: "
             + "; ".join(f"{name.replace('_', ' ')} networks {row['scale']:.2f} ({row['heldout_trajectories']} "
                         f"trajectories, {row['pairs']} samples)" for name, row in scales.items()) + ".", "",
             "| run | (step, point) pairs | ρ(spread, error) | error / spread: all, spread deciles | "
             "error / (scale × spread): all, spread deciles |", "| --- | --- | --- | --- | --- |"]
    for name, label in (("calibration.csv", "triaxial, validation path"),
                        ("biaxial/calibration_biaxial.csv", "biaxial test"),
                        ("footing/calibration_footing.csv", "strip footing")):
        if name not in tables:
            continue
        rows = tables[name]
        deciles, everything = rows[:-1], rows[-1]

        def span(column):
            values = [r[column] for r in deciles]
            return f"{everything[column]:.2f}, {min(values):.2f}–{max(values):.2f}"
        lines.append(f"| {label} | {everything['count']} | {everything['spearman_spread_error']:.2f} | "
                     f"{span('median_error_over_spread')} | {span('median_error_over_scaled_spread')} |")
    return "\n".join(lines) + "\n"


def render_reference_scatter(record: dict) -> str:
    """Other FEM–DEM runs of a problem against the pipeline's (bench_reference_scatter)."""
    f = record["figures"]
    finished = [r for r in f["rows"] if "error" not in r]
    failed = [r for r in f["rows"] if "error" in r]
    lines = [f"{record['date'].split()[0]}, commit {record['commit'][:7]}, {f['problem']}, against the run at "
             f"{f['base']} (the pipeline's):", ""]
    lines += problem_table(finished[1:], f["problem"])
    lines += [f"| {r['run']} | stopped: {r['error'][:120]} |" for r in failed]
    return "\n".join(lines) + "\n"


def render_adaptive_variants(record: dict) -> str:
    """The adaptive variants beside FEM–ML (bench_adaptive_variants): a table per load path of the
    specimen (--paths) and per problem with its controls (--problems)."""
    rows = [r for r in record["figures"] if "problem" in r]
    models = record["settings"].get("models")
    networks = f"the networks of training {Path(models).parent.name} (bench_trainings)" if models else \
        "the pipeline's networks"
    lines = [f"{record['date'].split()[0]}, commit {record['commit'][:7]}, {networks}:", ""]
    for path in dict.fromkeys(r["path"] for r in record["figures"] if "path" in r):
        lines += [f"| {path} | top force max error (% of peak) | stress MAE (kPa) | DEM particle-steps (replays) "
                  "| DEM points at the end | Newton iterations per step | wall |",
                  "| --- | --- | --- | --- | --- | --- | --- |"]
        lines += [f"| {r['variant']} | {r['top_force_pct_of_peak']:.2f} | {r['stress_mae_kpa']:.2f} | "
                  f"{r['dem_share_pct']:.1f} % ({r['replay_share_pct']:.1f} %) | {r['dem_points_final']} | "
                  f"{r['newton_iterations_per_step']:.2f} | {r['wall_s']:.1f} s |"
                  for r in record["figures"] if r.get("path") == path]
        lines.append("")
    for problem in dict.fromkeys(r["problem"] for r in rows):
        lines += problem_table([r for r in rows if r["problem"] == problem], problem)
    return "\n".join(lines) + "\n"


def render_problem_references(record: dict) -> str:
    """The RVE's friction and dilatancy, the biaxial band and the footing's pressure in one run."""
    label, f = run_label(record), record["figures"]
    angles = {row["test"]: row for row in rows_of(record, "rve_angles.csv")}
    triaxial, plane = angles["triaxial compression"], angles["plane strain compression"]
    band = pick(rows_of(record, "biaxial_bands.csv"), run="biaxial")
    footing = pick(rows_of(record, "footing.csv"), run="footing")
    steps = {key.split("/")[0]: w["particle_steps"] for key, w in dem_work(record).items()
             if key.split("/")[0] in ("biaxial", "footing")}
    lines = [f"{label} (`tables/rve_angles.csv`, `tables/biaxial_bands.csv`, `tables/footing.csv`):", "",
             "| quantity | value |", "| --- | --- |",
             f"| the RVE's peak friction angle, triaxial / plane strain | {triaxial['peak friction angle φ (deg)']:.1f}° / "
             f"{plane['peak friction angle φ (deg)']:.1f}° (mobilised at {plane['final axial strain (%)']:.0f} %: "
             f"{triaxial['mobilised friction at the end (deg)']:.1f}° / {plane['mobilised friction at the end (deg)']:.1f}°) |",
             f"| plane strain: Roscoe / Coulomb angle | {plane['Roscoe 45+ψ/2 (deg)']:.1f}° / "
             f"{plane['Coulomb 45+φ/2 (deg)']:.1f}° |",
             f"| biaxial test, {band['mesh'].replace('x', ' × ')} elements, {band['Gauss points']} RVEs | force peak "
             f"{band['peak force (kN/m)']:.1f} kN/m at {band['axial strain at peak (%)']:.2f} %; band onset "
             f"{band['band onset: axial strain (%)']:.2f} %; at the end the band carries "
             f"{band['band / mean shear strain at the end']:.2f} × the mean shear strain; "
             f"{band['inclination to σ3 (deg)']:.1f}° to σ3; width {band['width (mm)']:.1f} mm |",
             f"| strip footing, {footing['Gauss points']} RVEs | {footing['largest pressure (kPa)']:.0f} kPa = "
             f"{footing['largest pressure / q0']:.1f} q0 at s/B = {footing['settlement at the end s/B (%)']:.0f} %, "
             f"{footing['pressure gain over the last 20 % of the settlement (%)']:.0f} % gained over the last fifth; "
             f"{footing['largest pressure / (q0·N_q)']:.2f} of q0·N_q with the peak φ; p/p0 from "
             f"{footing['mean stress p/p0: smallest']:.2f} to {footing['mean stress p/p0: largest']:.2f} |"]
    if steps:
        lines.append("| FEM–DEM particle-steps | " + ", ".join(f"{name} {n:.2e}" for name, n in steps.items()) + " |")
    return "\n".join(lines) + "\n"


def render_rve_paths(record: dict) -> str:
    """What each RVE-path set of one run holds and what it cost."""
    f, label = record["figures"], run_label(record)
    if "rve_paths" not in f:  # a record made before bench_all described the sets: their wall times only
        return (f"{label}, the default training sources (`rve_paths.sets`): "
                + ", ".join(f"`{key.split('/')[1]}` {seconds:.0f} s" for key, seconds in f["rules_wall_s"].items()
                            if key.startswith("rve_paths/")) + " (wall, 2 workers).\n")
    reference = f["dem_work"]["fem_dem/path1"]["particle_steps"]
    lines = [f"{label}, the default training sources (`rve_paths.sets`):", "",
             "| set | trajectories | evaluations | particle-steps | wall | largest axial / lateral strain "
             "| largest ε_s | lost contact |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    total = 0
    for name, s in f["rve_paths"].items():
        work = f["dem_work"][f"rve_paths/{name}"]
        total += work["particle_steps"]
        families = ", ".join(f"{n} {family.replace('_', ' ')}" for family, n in s["families"].items())
        lines.append(f"| `{name}` | {families} × {s['steps']} steps | {s['evaluations']} | {work['particle_steps']:.2e} | "
                     f"{f['rules_wall_s'].get(f'rve_paths/{name}', work['wall_s']):.0f} s | "
                     f"{s['largest_axial_strain_pct']:.1f} % / {s['largest_lateral_strain_pct']:.1f} % | "
                     f"{s['largest_shear_strain_pct']:.1f} % | {s['lost_contact']} |")
    lines += ["", f"Together {total:.2e} particle-steps, {100 * total / reference:.0f} % of FEM–DEM Path1's."]
    return "\n".join(lines) + "\n"


def render_ensemble_resampling(record: dict) -> str:
    """Spread against error per ensemble resampling and training seed (bench_ensemble_resampling)."""
    f = record["figures"]
    lines = [f"{record['date'].split()[0]}, commit {record['commit'][:7]}, {f['test_points']} test points:", "",
             "| resampling | seed | ρ(spread, error), median over steps | steps with ρ ≥ 0.5 "
             "| ρ(distance to the training states, error) | error / spread, median "
             "| error > 2 × spread | mean ‖σ − σ_ref‖ (kPa) |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in f["rows"]:
        lines.append(f"| `{r['resampling']}` | {r['seed']} | {r['spearman_median']:.2f} | "
                     f"{100 * r['spearman_steps_above_0.5']:.0f} % | {r['distance_spearman_median']:.2f} | "
                     f"{r['error_over_spread_median']:.2f} | "
                     f"{100 * r['share_error_above_twice_spread']:.0f} % | {r['stress_mae_kpa']:.1f} |")
    return "\n".join(lines) + "\n"




def render_trainings(record: dict) -> str:
    """The default networks and independent trainings of them, on the validation path and the problems
    (bench_trainings)."""
    lines = [f"{record['date'].split()[0]}, commit {record['commit'][:7]}; force and εv: largest error in % of the "
             "reference's peak (up to / after its peak); ρ: Spearman's over the points of each step after the peak, "
             "median; \"driven\": FEM–ML's networks along the reference's strain histories, no FEM (the "
             "material's error alone; its force that of their stresses in virtual work, its εv the reference's):",
             "",
             "| run | training seed | force | εv | band Δ, onset Δ | σ MAE in / out of the band or under the footing "
             "(kPa) | ρ(spread, error) / ρ(distance, error) | median ‖σ − σ_ref‖ after the peak (p0) "
             "| error / spread, error / (scale × spread) | DEM share |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in sorted(record["figures"]["rows"], key=lambda r: (r["what"], r["training seed"])):
        get = r.get
        force = f"{r['force: largest error (% of peak)']:.2f} %"
        if get("force: up to the peak (%)") is not None:
            force += f" ({r['force: up to the peak (%)']:.1f} / {r['force: after the peak (%)']:.1f})"
        band = (f"{r['inclination − reference (deg)']:+.1f}°, {_number(get('onset − reference (% strain)'))} %"
                if get("inclination − reference (deg)") is not None else "–")
        inside = get("stress MAE in the band (kPa)", get("stress MAE under the footing (kPa)"))
        outside = get("stress MAE outside the band (kPa)", get("stress MAE elsewhere (kPa)"))
        mae = f"{_number(inside, 1)} / {_number(outside, 1)}" if inside is not None else "–"
        rho = (f"{_number(get('spread–error rank correlation (after the peak)'))} / "
               f"{_number(get('distance–error rank correlation (after the peak)'))}"
               if get("distance–error rank correlation (after the peak)") is not None else "–")
        median = _number(get("median stress error after the peak (p0)"))
        share = get("DEM particle-steps (% of the reference's)")
        calibrated = (f"{_number(get('median error / spread'))}, {_number(get('median error / (scale × spread)'))}"
                      if get("median error / (scale × spread)") is not None else "–")
        lines.append(f"| {r['what']} | {r['training seed']} | {force} | "
                     f"{r['volumetric strain: largest error (% of its peak)']:.1f} % | {band} | {mae} | {rho} | {median} | "
                     f"{calibrated} | {'–' if share is None else f'{share:.1f} %'} |")
    return "\n".join(lines) + "\n"


def render_strain_rate(record: dict) -> str:
    """FEM–DEM of one path at each RVE strain rate against the slowest (bench_strain_rate)."""
    rows = record["figures"]["rows"]
    lines = [f"{record['date'].split()[0]}, commit {record['commit'][:7]}, against {rows[0]['against']:g} /s:", "",
             "| strain rate | inertial number | DEM evaluations / step | particle-steps (ratio) "
             "| top force, max diff. (% of peak) | volumetric strain, max diff. (% of peak) | stress MAE (kPa) |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| {r['strain_rate']:g} /s | {r['inertial_number']:.1e} | {r['evaluations_per_step']:.2f} | "
                     f"{r['particle_steps']:.2e} ({r['particle_steps_ratio']:.2f}) | {r['top_force_diff_pct']:.2f} | "
                     f"{r['volumetric_strain_diff_pct']:.2f} | {r['stress_mae_kpa']:.2f} |")
    return "\n".join(lines) + "\n"


def render_fem_ml_vs_dem(record: dict) -> str:
    """One line: FEM–ML against FEM–DEM on the same mesh and path (bench_fem_ml_vs_dem)."""
    f, config = record["figures"], record["settings"].get("config_difference", {})
    pressure = config.get("specimen", {}).get("confining_pressure")
    where = f"confining pressure {pressure / 1e3:g} kPa, " if pressure else ""

    def reached(steps: int) -> str:  # a run that stopped early is compared over the steps it reached
        return "" if steps >= f["steps"] else f" (it stopped after {steps} of the {f['steps']} steps)"

    return (f"{record['date'].split()[0]}, commit {record['commit'][:7]}: {where}{f['path']}, {f['steps']} steps, "
            f"{f['gauss_points']} RVEs of {f['n_spheres']} spheres; "
            f"{'the networks of a pipeline run' if f['networks'].startswith('pipeline models') else f['networks']}. "
            f"FEM–ML against FEM–DEM: "
            f"top force {f['fem_ml_top_force_error_pct']:.1f} %, volumetric strain "
            f"{f['fem_ml_volumetric_strain_error_pct']:.0f} % of the peak (largest over the path){reached(f['fem_ml']['steps'])}."
            + "".join(f" With {label}: top force {run['top_force_error_pct']:.1f} %, volumetric strain "
                      f"{run['volumetric_strain_error_pct']:.0f} %{reached(run['steps'])}."
                      for label, run in f.get("fem_ml_compared", {}).items())
            + "\n")


RENDERERS = {"headline": render_headline, "rules": render_rules, "fem_ml": render_fem_ml, "problems": render_problems,
             "problem_references": render_problem_references, "rve_paths": render_rve_paths,
             "ensemble_resampling": render_ensemble_resampling, "strain_rate": render_strain_rate,
             "fem_ml_vs_dem": render_fem_ml_vs_dem, "trainings": render_trainings,
             "reference_scatter": render_reference_scatter, "adaptive_variants": render_adaptive_variants,
             "calibration": render_calibration}


def rewrite(text: str, document: str) -> str:
    def block(match):
        record_path, renderer = ROOT / match.group(2), match.group(3)
        if renderer not in RENDERERS:
            raise ValueError(f"{document}: unknown renderer {renderer!r} (known: {sorted(RENDERERS)})")
        try:
            record = json.loads(record_path.read_text())
        except (OSError, json.JSONDecodeError) as error:
            raise ValueError(f"{document}: record {match.group(2)}: {error}") from error
        return match.group(1) + RENDERERS[renderer](record) + match.group(5)

    return BLOCK.sub(block, text)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 if a block is stale")
    args = parser.parse_args(argv)
    stale = []
    for document in documents():
        path = ROOT / document
        text = path.read_text()
        if not BLOCK.search(text):
            continue
        new = rewrite(text, document)
        if new != text:
            stale.append(document)
            if not args.check:
                path.write_text(new)
    if args.check and stale:
        print(f"measured blocks differ from their records in {', '.join(stale)}: run python bench/update_docs.py",
              file=sys.stderr)
        return 1
    print("rewrote " + ", ".join(stale) if stale and not args.check else "measured blocks are current")
    return 0


if __name__ == "__main__":
    sys.exit(main())
