"""Rule fem_elastoplastic: the triaxial test on one load path with the analytic elastoplastic
model at every Gauss point, written in the data contract."""

from granular_multiscale.config import validate_config
from granular_multiscale.data import write_run
from granular_multiscale.fem.triaxial import TriaxialProblem
from granular_multiscale.materials import make_material
from granular_multiscale.paths import load_paths_from_config
from granular_multiscale.runlog import setup_logging, timed_rule


def main(config: dict, path_name: str, output: str, log: str | None) -> None:
    config = validate_config(config)
    logger = setup_logging(log)
    with timed_rule(logger, f"fem_elastoplastic {path_name}"):
        problem = TriaxialProblem.from_config(config)
        load_path = load_paths_from_config(config)[path_name]
        logger.info(
            "mesh %s elements (%d Gauss points), %s platens, p0 = %.0f Pa, path %s with %d steps",
            "x".join(map(str, problem.elements)), problem.n_gauss_points, problem.platen,
            problem.confining_pressure, path_name, load_path.n_steps,
        )
        with make_material("elastoplastic", problem.n_material_points, config) as material:
            ds = problem.run(material, load_path, logger=logger)
        write_run(ds, output, config)
        logger.info("wrote %s", output)


if __name__ == "__main__" or "snakemake" in globals():
    main(dict(snakemake.config), snakemake.wildcards.path, snakemake.output[0], snakemake.log[0])  # noqa: F821
