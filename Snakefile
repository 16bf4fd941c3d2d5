# Granular multiscale workflow: RVE -> FEM–DEM (or the elastoplastic reference) -> dataset
# -> NNσ/ND training -> FEM–ML -> figures, tables, report.
#
#   snakemake -j2 all                                   default scale (config/config.yaml)
#   snakemake -j2 all --configfile config/tiny.yaml     tests/CI scale
#   snakemake --report results/report.html              the HTML report of a finished run

import sys
from pathlib import Path

from granular_multiscale.config import ConfigError, read_config_file

# Snakemake's message for a broken config file names neither the file nor the line; read the
# default config first for one that does. (Files given with --configfile are read by Snakemake's
# command line before this file runs: a broken one gets Snakemake's message, a missing one its
# traceback; --verbose shows YAML's line there.) Like the configfile directive below, relative to
# the working directory; a working directory without it leaves the choice to Snakemake (it runs
# with the --configfile files alone).
try:
    if Path("config/config.yaml").exists():
        read_config_file("config/config.yaml")
except ConfigError as error:
    sys.exit(f"Configuration error: {error}")


configfile: "config/config.yaml"


include: "workflow/rules/common.smk"
include: "workflow/rules/reference.smk"
include: "workflow/rules/dem.smk"
include: "workflow/rules/convergence.smk"
include: "workflow/rules/surrogate.smk"
include: "workflow/rules/adaptive.smk"
include: "workflow/rules/analysis.smk"
include: "workflow/rules/problems.smk"
include: "workflow/rules/problem_surrogate.smk"


report: "workflow/report/workflow.rst"


onstart:
    take_output_lock()


onsuccess:
    output_lock.release(L.out)


onerror:
    output_lock.release(L.out)


rule all:
    input:
        PLAN.all_targets(),
    default_target: True
