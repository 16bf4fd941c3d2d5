# Shared by all rule files: config validation, corrupt outputs set aside, the output lock, the plan.
import sys

from granular_multiscale import integrity, output_lock
from granular_multiscale.config import ConfigError, reference_newton_config, validate_config
from granular_multiscale.drivers.problems import check_problems
from granular_multiscale.plan import Plan

try:
    config.update(validate_config(config))
    check_problems(config)  # the problems' meshes, weak zones and load paths, before any rule runs
except (ConfigError, ValueError) as error:
    sys.exit(f"Configuration error: {error}")

# Every output path, run set, label and rerun trigger of the rule files comes from the plan
# (granular_multiscale/plan.py); the rule files share nothing else.
PLAN = Plan(config)
L = PLAN.layout

# Job order under `-j N`: Snakemake starts the ready jobs of the largest summed priority that fit
# the cores. The DEM runs (which take every worker) go first, so that the one-core trainings then
# run side by side with no DEM run left to wait; of those, ND first (the adaptive runs, two-core
# again, wait for it), then NNσ, then the no-history ablation.
DEM_PRIORITY = 10  # above any two trainings together
TRAINING_PRIORITY = {"tangent": 3, "sigma": 2, "sigma_nohist": 1, "tangent_nohist": 1}


def set_aside_corrupt_outputs():
    """Every output whose bytes no longer match the checksum recorded when it was written is
    moved to {output_dir}/corrupt/<time>/ before Snakemake plans the jobs, with what was built from it
    (Snakemake would not rebuild a missing file whose dependants are up to date), so this run
    rebuilds them. Not while another workflow holds the output directory, nor in the processes
    that run single jobs."""
    from snakemake.logging import logger

    if not workflow.is_main_process or output_lock.held_by_other(L.out):
        return
    corrupt = integrity.scan(L.out)
    if not corrupt:
        return
    inputs = integrity.snakemake_inputs()
    stale = [(path, f"built from {', '.join(str(p) for p, _ in corrupt)}")
             for path in integrity.built_from([p for p, _ in corrupt], inputs)]
    folder = integrity.set_aside(L.out, corrupt + stale)
    for path, reason in corrupt + stale:
        logger.warning(f"{path} set aside in {folder}: {reason}; this run rebuilds it")
    if not inputs:
        logger.warning("Snakemake's records of what was built from it are not in this working directory: "
                       f"rerun with -R {' '.join(str(p) for p, _ in corrupt)} to rebuild that too")


def take_output_lock():
    """onstart: no second workflow, from any clone, writes the output directory while this one does."""
    from snakemake.logging import logger

    try:
        output_lock.acquire(L.out, warn=logger.warning)
    except output_lock.OutputLockedError as error:
        sys.exit(f"Output directory locked: {error}")


set_aside_corrupt_outputs()


wildcard_constraints:
    path="|".join(PLAN.path_names),
