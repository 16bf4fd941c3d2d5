# Granular multiscale workflow: RVE -> FEM–DEM (or the elastoplastic reference) -> dataset
# -> NNσ/ND training -> FEM–ML -> figures, tables, report.
#
#   snakemake -j2 all                                   default scale (config/config.yaml)
#   snakemake -j2 all --configfile config/tiny.yaml     tests/CI scale
#   snakemake --report results/report.html              the HTML report of a finished run

configfile: "config/config.yaml"


include: "workflow/rules/common.smk"
include: "workflow/rules/reference.smk"
include: "workflow/rules/dem.smk"
include: "workflow/rules/convergence.smk"
include: "workflow/rules/surrogate.smk"
include: "workflow/rules/adaptive.smk"
include: "workflow/rules/analysis.smk"
include: "workflow/rules/problems.smk"


report: "workflow/report/workflow.rst"


rule all:
    input:
        ALL_TARGETS,
    default_target: True
