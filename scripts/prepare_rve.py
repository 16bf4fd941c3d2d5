"""Rules rve, rve_spheres, rve_pressure and rve_weak: consolidate the RVE packing(s) with YADE; write
them and a summary JSON. rve_pressure consolidates to another pressure than the specimen's; rve_weak
makes one packing (seed `seed`) whose friction is restored to another value."""

from granular_multiscale.config import validate_config
from granular_multiscale.dem.run import prepare_rves
from granular_multiscale.runlog import setup_logging, timed_rule


def main(config: dict, packings: list[str], summary: str, log: str | None, threads: int,
         n_spheres: int | None = None, friction: float | None = None, pressure: float | None = None) -> None:
    config = validate_config(config)
    if pressure is not None:  # rule rve_pressure: consolidated at g·p0 (Pa)
        config["specimen"]["confining_pressure"] = pressure
    if n_spheres is not None:  # rule rve_spheres: another sphere count than dem.n_spheres
        config["dem"]["n_spheres"] = n_spheres
    if friction is not None:  # rule rve_weak: packing 0 restored to a weaker friction
        config["dem"].update(friction=friction, n_packings=1)
    logger = setup_logging(log)
    with timed_rule(logger, f"rve ({len(packings)} packing(s) of {config['dem']['n_spheres']} spheres)"):
        prepare_rves(config, packings, summary, threads=threads, logger=logger)


if __name__ == "__main__" or "snakemake" in globals():
    main(dict(snakemake.config), list(snakemake.output.packings), snakemake.output.summary,  # noqa: F821
         snakemake.log[0], snakemake.threads, getattr(snakemake.params, "n_spheres", None),  # noqa: F821
         getattr(snakemake.params, "friction", None), snakemake.params.pressure)  # noqa: F821
