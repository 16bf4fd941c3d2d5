"""Rules adaptive, adaptive_active: the triaxial test on one load path with the surrogate at every
Gauss point and a YADE RVE where its indicator reaches the threshold, written in the data contract
plus the mode of every point per step, and the DEM answers of the points that ran DEM (training
data of the active-learning round). Resumes from its checkpoint."""

from granular_multiscale.config import validate_config
from granular_multiscale.drivers.adaptive import run_adaptive
from granular_multiscale.runlog import setup_logging, timed_rule


def main(config: dict, path_name: str, threshold: float, packings: list[str], sigma: str, tangent_model: str,
         tangent: str, output: str, trajectories: str, checkpoint: str, log: str | None, threads: int,
         allow_partial: bool) -> None:
    config = validate_config(config)
    logger = setup_logging(log)
    # local pool: one worker per core the rule got; Dask: dem.n_workers actors on the cluster
    workers = threads if config["dem"]["executor"] == "local" else config["dem"]["n_workers"]
    with timed_rule(logger, f"adaptive {path_name} at threshold {threshold:g}"):
        run_adaptive(config, path_name, threshold, packings, sigma, tangent_model, tangent, output, checkpoint,
                     workers, logger=logger, allow_partial=allow_partial, trajectories=trajectories)


if "snakemake" in globals():
    sm = snakemake  # noqa: F821
    main(dict(sm.config), sm.wildcards.path, float(sm.params.threshold), list(sm.input.packings), sm.input.sigma,
         sm.input.tangent, sm.params.tangent, sm.output.run, sm.output.trajectories, sm.params.checkpoint, sm.log[0],
         sm.threads,
         bool(sm.params.allow_partial))
