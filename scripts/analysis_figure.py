"""Rules figure_*: one figure of the report, drawn by granular_multiscale.analysis.products.

The rule's params name the product (params.kind) and pass labels and the config's
``analysis`` section; inputs and outputs are named (see workflow/rules/analysis.smk)."""

from granular_multiscale.analysis import products
from granular_multiscale.runlog import setup_logging, timed_rule


def main(sm) -> None:
    logger = setup_logging(sm.log[0])
    p = sm.params
    settings = p.settings
    with timed_rule(logger, f"{sm.rule} -> {', '.join(map(str, sm.output))}"):
        if p.kind == "error_map":
            products.make_error_map(sm.input.reference, sm.input.surrogate, sm.input.train, sm.input.heldout,
                                    sm.output[0], settings, path_label=p.path_label,
                                    reference_label=p.reference_label, surrogate_label=p.surrogate_label)
        elif p.kind == "stress_strain":
            runs = dict(zip(p.labels, sm.input.runs))
            outs = dict(zip(p.points, sm.output))
            chosen, _ = products.make_stress_strain(runs, sm.input.train, sm.input.heldout, outs, settings,
                                                    path_label=p.path_label)
            logger.info("Gauss points: %s", chosen)
        elif p.kind == "global_response":
            products.make_global_response(dict(zip(p.labels, sm.input.runs)), sm.output[0], settings,
                                          path_label=p.path_label)
        elif p.kind == "fields":
            products.make_field_figure(sm.input.reference, sm.input.surrogate, sm.wildcards.quantity,
                                       sm.output[0], settings, path_label=p.path_label,
                                       reference_label=p.reference_label, surrogate_label=p.surrogate_label)
        elif p.kind == "training_curves":
            products.make_training_curves(dict(zip(p.labels, sm.input.curves)), sm.output[0], settings)
        elif p.kind == "speed_vs_error":
            products.make_speed_vs_error(sm.input.speedup, sm.input.accuracy, sm.output[0], settings,
                                         curve=p.get("curve", []))
        elif p.kind == "mode_map":
            products.make_mode_map(dict(zip(p.labels, sm.input.runs)), sm.output[0], settings,
                                   path_label=p.path_label)
        else:
            raise ValueError(f"unknown figure kind {p.kind!r}")


if "snakemake" in globals():
    main(snakemake)  # noqa: F821
