# Shared helpers of all rule files: config validation, output locations, the list of targets.
import sys

from granular_multiscale import integrity, output_lock
from granular_multiscale.config import ConfigError, validate_config
from granular_multiscale.drivers.problems import check_problems
from granular_multiscale.paths import load_paths_from_config

try:
    config.update(validate_config(config))
    check_problems(config)  # the problems' meshes, weak zones and load paths, before any rule runs
except (ConfigError, ValueError) as error:
    sys.exit(f"Configuration error: {error}")

OUT = config["output_dir"].rstrip("/")


def set_aside_corrupt_outputs():
    """Every output whose bytes no longer match the checksum recorded when it was written is
    moved to {OUT}/corrupt/<time>/ before Snakemake plans the jobs, with what was built from it
    (Snakemake would not rebuild a missing file whose dependants are up to date), so this run
    rebuilds them. Not while another workflow holds the output directory, nor in the processes
    that run single jobs."""
    from snakemake.logging import logger

    if not workflow.is_main_process or output_lock.held_by_other(OUT):
        return
    corrupt = integrity.scan(OUT)
    if not corrupt:
        return
    inputs = integrity.snakemake_inputs()
    stale = [(path, f"built from {', '.join(str(p) for p, _ in corrupt)}")
             for path in integrity.built_from([p for p, _ in corrupt], inputs)]
    folder = integrity.set_aside(OUT, corrupt + stale)
    for path, reason in corrupt + stale:
        logger.warning(f"{path} set aside in {folder}: {reason}; this run rebuilds it")
    if not inputs:
        logger.warning("Snakemake's records of what was built from it are not in this working directory: "
                       f"rerun with -R {' '.join(str(p) for p, _ in corrupt)} to rebuild that too")


def take_output_lock():
    """onstart: no second workflow, from any clone, writes {OUT} while this one does."""
    from snakemake.logging import logger

    try:
        output_lock.acquire(OUT, warn=logger.warning)
    except output_lock.OutputLockedError as error:
        sys.exit(f"Output directory locked: {error}")


set_aside_corrupt_outputs()
PATHS = load_paths_from_config(config)
PATH_NAMES = list(PATHS)
REFERENCE = "fem_dem" if config["reference_material"] == "dem" else "fem_elastoplastic"

# Each rule file appends the final products of its stage; `rule all` asks for all of them.
ALL_TARGETS = []


wildcard_constraints:
    path="|".join(PATH_NAMES),


def reference_run(path):
    """The reference run (FEM–DEM or the elastoplastic model) of a load path."""
    return f"{OUT}/{REFERENCE}/{path}.h5"

