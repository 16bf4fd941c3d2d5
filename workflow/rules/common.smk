# Shared helpers of all rule files: config validation, output locations, the list of targets.
import sys

from granular_multiscale.config import ConfigError, validate_config
from granular_multiscale.drivers.problems import check_problems
from granular_multiscale.paths import load_paths_from_config

try:
    config.update(validate_config(config))
    check_problems(config)  # the problems' meshes, weak zones and load paths, before any rule runs
except (ConfigError, ValueError) as error:
    sys.exit(f"Configuration error: {error}")

OUT = config["output_dir"].rstrip("/")
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

