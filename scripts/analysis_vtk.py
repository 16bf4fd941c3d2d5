"""Rules vtk_export and vtk_problem: one VTU per load step and a PVD collection of a run, for ParaView."""

from granular_multiscale.analysis import products
from granular_multiscale.runlog import setup_logging, timed_rule


def main(sm) -> None:
    logger = setup_logging(sm.log[0])
    with timed_rule(logger, f"vtk_export {sm.input[0]} -> {sm.output[0]}"):
        products.make_vtk(sm.input[0], sm.output[0], stem=sm.params.get("stem", None) or sm.wildcards.path)


if "snakemake" in globals():
    main(snakemake)  # noqa: F821
