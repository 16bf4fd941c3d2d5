"""Rule validation_tables: FEM–ML runs of every validation (and training) path against the
reference run of that path, per method and load phase -> tables/validation_by_phase.{csv,html}."""

from granular_multiscale.analysis import products
from granular_multiscale.runlog import setup_logging, timed_rule


def main(sm) -> None:
    logger = setup_logging(sm.log[0])
    p = sm.params
    with timed_rule(logger, f"{sm.rule} -> {', '.join(map(str, sm.output))}"):
        # sm.input.runs: for each (path, role) of p.cases, one run file per label, in order
        n = len(p.labels)
        files = list(sm.input.runs)
        if len(files) != n * len(p.cases):
            raise ValueError(f"{len(files)} run files for {len(p.cases)} paths × {n} runs ({p.labels})")
        cases = [(path, role, dict(zip(p.labels, files[i * n:(i + 1) * n]))) for i, (path, role) in enumerate(p.cases)]
        table = products.make_validation_table(cases, sm.output.csv, sm.output.html,
                                               reference_label=p.reference_label)
        logger.info("%s", table.to_string(index=False))


if "snakemake" in globals():
    main(snakemake)  # noqa: F821
