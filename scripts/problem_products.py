"""Rules of workflow/rules/problems.smk that draw or tabulate the problems beyond the triaxial
specimen (granular_multiscale.analysis.problems); params.kind names the product."""

import numpy as np

from granular_multiscale.analysis import problem_surrogate, problems
from granular_multiscale.analysis.tables import write_csv
from granular_multiscale.atomic import atomic_path
from granular_multiscale.data import read_run
from granular_multiscale.runlog import setup_logging, timed_rule
from granular_multiscale.surrogate import dataset

#: the field maps of each problem
FIELDS = {"biaxial": ["shear_strain", "volumetric_strain", "mean_stress"],
          "footing": ["mean_stress", "shear_strain", "deviatoric_stress"]}


def _runs(labels, files) -> dict:
    return {label: read_run(f) for label, f in zip(labels, files)}


def _write_table(table, out, logger) -> None:
    write_csv(table, out.csv)
    with atomic_path(out.html) as tmp, open(tmp, "w") as f:
        f.write(table.to_html(index=False, float_format=lambda v: f"{v:.4g}", border=0))
    logger.info("%s\n%s", out.csv, table.to_string(index=False))


def field_steps(run) -> list[int]:
    """The steps of a problem's field figure: the peak of the load force, halfway to the end, the end."""
    peak = int(np.argmax(run["load_force"].values))
    last = run.sizes["step"] - 1
    return sorted({peak, (peak + last) // 2, last})


def main(sm) -> None:
    logger = setup_logging(sm.log[0])
    p = sm.params
    with timed_rule(logger, f"{sm.rule} -> {', '.join(map(str, sm.output))}"):
        settings = p.get("settings", {}) or {}
        dpi = int(settings.get("dpi", 120))
        if p.kind == "angles":
            _write_table(problems.angles_table(_runs(p.labels, sm.input.runs)), sm.output, logger)
        elif p.kind == "response":
            problems.response_figure(_runs(p.labels, sm.input.runs), sm.output[0], title=p.title, dpi=dpi)
        elif p.kind == "fields":
            run = read_run(sm.input.run)
            problem = str(run.attrs["problem"])
            problems.field_figure(run, FIELDS[problem], field_steps(run), sm.output[0], title=p.title,
                                  deformation_scale=float(settings.get("deformation_scale", 1.0)), dpi=dpi)
        elif p.kind == "bands":
            angles = problems.read_table(sm.input.angles)
            _write_table(problems.band_table(_runs(p.labels, sm.input.runs), angles, p.grain_diameter), sm.output,
                         logger)
        elif p.kind == "footing":
            angles = problems.read_table(sm.input.angles)
            _write_table(problems.footing_table(_runs(p.labels, sm.input.runs), angles), sm.output, logger)
        elif p.kind == "surrogate":
            runs = _runs(p.labels, sm.input.runs)
            reference, others = runs[p.labels[0]], {k: v for k, v in runs.items() if k != p.labels[0]}
            _write_table(problem_surrogate.comparison_table(reference, runs), sm.output, logger)
            problems.response_figure(runs, sm.output.response, title=f"{p.title}: every method", dpi=dpi)
            problem_surrogate.error_map_figure(reference, others, sm.output.error_map,
                                               title=f"{p.title}: stress error against {p.labels[0]}",
                                               deformation_scale=float(settings.get("deformation_scale", 1.0)),
                                               dpi=dpi)
        elif p.kind == "visited_states":
            runs = {label: read_run(f, required=("strain", "stress")) for label, f in zip(p.labels, sm.input.runs)}
            history = dataset.history_selection(p.history)
            training = problem_surrogate.TrainingStates(dataset.features(dataset.read_dataset(sm.input.dataset), history))
            _write_table(problem_surrogate.state_ranges(runs, float(p.pressure), training, history), sm.output, logger)
        elif p.kind == "mesh_study":
            runs = _runs(p.labels, sm.input.runs)
            _write_table(problems.mesh_table(runs), sm.output, logger)
            problems.response_figure(runs, sm.output.figure, title="Biaxial test: the same test on several meshes",
                                     dpi=dpi)
        else:
            raise ValueError(f"unknown product kind {p.kind!r}")


if "snakemake" in globals():
    main(snakemake)  # noqa: F821
