"""Rules table_* and headline: the report's tables (CSV + HTML), its headline numbers (JSON) and
headline page (HTML)."""

from granular_multiscale.analysis import products, tables
from granular_multiscale.runlog import setup_logging, timed_rule


def main(sm) -> None:
    logger = setup_logging(sm.log[0])
    p = sm.params
    with timed_rule(logger, f"{sm.rule} -> {', '.join(map(str, sm.output))}"):
        if p.kind == "speedup":
            machine = tables.machine_description()
            table = products.make_speedup_outputs(
                dict(zip(p.labels, sm.input.runs)), sm.output.csv, sm.output.html, path_label=p.path_label,
                paper_reference=p.paper_reference,
                machine=f"{machine['cores']} cores of {machine['cpu']}",
            )
        elif p.kind == "accuracy":
            table = products.make_accuracy_table(dict(zip(p.labels, sm.input.runs)), sm.input.train,
                                                 sm.input.heldout, sm.output.csv, sm.output.html,
                                                 path_label=p.path_label)
        elif p.kind == "surrogate_cost":
            items = [(what, how, path) for (what, how), path in zip(p.cost_items, sm.input.cost_files)]
            table = products.make_surrogate_cost(items, sm.input.speedup, sm.output.csv, sm.output.html,
                                                 reference_label=p.reference_label,
                                                 surrogate_label=p.surrogate_label, path_label=p.path_label)
        elif p.kind == "headline":
            table = products.make_headline(sm.input.speedup, sm.input.accuracy, sm.output.json, config=sm.config,
                                           reference_label=p.reference_label, surrogate_label=p.surrogate_label,
                                           ablation_label=p.ablation_label, reference_run=sm.input.reference,
                                           cost_csv=sm.input.cost, page=sm.output.page)
        else:
            raise ValueError(f"unknown table kind {p.kind!r}")
        logger.info("%s", table)


if "snakemake" in globals():
    main(snakemake)  # noqa: F821
