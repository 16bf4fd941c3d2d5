"""Rules adaptive, adaptive_active, problem_adaptive, problem_adaptive_control: a load path of the
triaxial specimen or of another problem (params.problem) with the surrogate at every Gauss point and
a YADE RVE where its indicator reaches the threshold (or, for a control, an analytic model with the
promotions of a network run), written in the data contract plus the mode of every point per step,
and the DEM answers of the points that ran DEM (training data of the active-learning round).
Resumes from its checkpoint."""

from granular_multiscale.config import problem_adaptive_config, validate_config
from granular_multiscale.drivers.adaptive import run_adaptive
from granular_multiscale.runlog import setup_logging, timed_rule


def main(config: dict, path_name: str, threshold: float, packings: list[str], sigma: str, tangent_model: str,
         tangent: str, output: str, trajectories: str, checkpoint: str, log: str | None, threads: int,
         allow_partial: bool, problem: str = "triaxial", weak_packing: str | None = None,
         control: str | None = None, schedule_from: str | None = None) -> None:
    config = validate_config(config)
    if problem != "triaxial":  # the problem's own adaptive settings (its threshold comes as `threshold`)
        config = problem_adaptive_config(config, problem)[0]
    logger = setup_logging(log)
    # local pool: one worker per core the rule got; Dask: dem.n_workers actors on the cluster
    workers = threads if config["dem"]["executor"] == "local" else config["dem"]["n_workers"]
    what = f"adaptive {problem} {path_name} at threshold {threshold:g}" + (f", control {control}" if control else "")
    with timed_rule(logger, what):
        run_adaptive(config, path_name, threshold, packings, sigma, tangent_model, tangent, output, checkpoint,
                     workers, logger=logger, allow_partial=allow_partial, trajectories=trajectories, problem=problem,
                     weak_packing=weak_packing, control=control, schedule_from=schedule_from)


if "snakemake" in globals():
    sm = snakemake  # noqa: F821
    inputs = dict(sm.input.items())
    main(dict(sm.config), sm.params.get("path_name") or sm.wildcards.path, float(sm.params.threshold),
         list(sm.input.packings), inputs.get("sigma"), inputs.get("tangent"), sm.params.tangent, sm.output.run,
         sm.output.trajectories, sm.params.checkpoint, sm.log[0], sm.threads, bool(sm.params.allow_partial),
         problem=sm.params.get("problem") or "triaxial", weak_packing=next(iter(inputs.get("weak_packing") or []), None),
         control=sm.params.get("control"), schedule_from=inputs.get("schedule_from"))
