# Surrogate stage: dataset -> NNσ/ND training (with and without history variables) -> FEM–ML
# runs -> accuracy tables against the reference runs.
#
#   dataset                {OUT}/dataset/train.h5, heldout.h5 from the training sources (surrogate.training_sources:
#                          reference runs of load paths, RVE-path sets), held out by trajectory class
#   train_<network>        {OUT}/models/nn_<network>.pt, {OUT}/training/<network>.csv (loss per epoch),
#                          <network>_mae.csv (final MAE per component), <network>_loss.png
#                          networks: sigma, tangent (9 inputs), sigma_nohist, tangent_nohist (6 inputs)
#   fem_ml                 {OUT}/fem_ml/{path}.h5          tangent from config surrogate.tangent
#   fem_ml_nohist          {OUT}/fem_ml_nohist/{path}.h5   the ablation without history variables
#   fem_ml_tangent         {OUT}/fem_ml_{nn,autodiff}/{path}.h5   Newton iterations of both tangents
#   metrics                {OUT}/tables/*.csv
#   dataset_active, train_{sigma,tangent}_active   the active-learning round (adaptive.smk): the same
#                          sources plus the DEM answers of adaptive runs -> {OUT}/active/dataset, {OUT}/active/models
from granular_multiscale.adaptive import threshold_label

SURROGATE = config["surrogate"]
TRAINING_PATH = config["training_path"]
VALIDATION_PATH = config["validation_path"]
# what trains the networks: reference runs of load paths and RVE-path sets ("rve_paths:<set>")
TRAINING_SOURCES = SURROGATE["training_sources"] or [TRAINING_PATH]
TRAINING_RUN_PATHS = [s for s in TRAINING_SOURCES if not s.startswith("rve_paths:")]
TRAINING_RVE_SETS = [s.split(":", 1)[1] for s in TRAINING_SOURCES if s.startswith("rve_paths:")]
# every load path the training did not use is a validation case; FEM–ML runs every path
VALIDATION_PATHS = [p for p in PATH_NAMES if p not in TRAINING_RUN_PATHS]
ML_PATHS = list(dict.fromkeys([VALIDATION_PATH, *VALIDATION_PATHS, *TRAINING_RUN_PATHS, TRAINING_PATH]))
# network name -> (targets, uses the history variables)
NETWORKS = {
    "sigma": ("sigma", True),
    "tangent": ("tangent", True),
    "sigma_nohist": ("sigma", False),
    "tangent_nohist": ("tangent", False),
}
SURROGATE_THREADS = SURROGATE["torch_threads"]
# one round of active learning (adaptive.active_learning): the adaptive runs at its threshold on its
# paths write the DEM answers of their promoted points ({OUT}/adaptive/<label>/dem_points/<path>.h5), which
# join the training sources of a second training round
# (here, not in adaptive.smk: the training rounds below need them)
ADAPTIVE_PATHS = config["adaptive"]["paths"] or [VALIDATION_PATH]
ACTIVE = config["adaptive"]["active_learning"]
ACTIVE_LABEL = threshold_label(ACTIVE["threshold"])
ACTIVE_PATHS = ACTIVE["paths"] or ADAPTIVE_PATHS
# the keys of `surrogate` that change a trained network (only these re-run the training rules)
TRAINING_KEYS = [
    "hidden_layers", "hidden_units", "activation", "batch_size", "learning_rate", "epochs", "ensemble_size", "lr_schedule",
    "final_learning_rate", "jacobian_loss_weight", "loss", "log_every", "history_variables", "device",
    "torch_threads",
]


def model_file(network, round=""):
    return f"{OUT}/{round}models/nn_{network}.pt"


# training rounds, by the folder prefix of their outputs: the pipeline's networks, and those of the
# active-learning round (NNσ and ND with history only: what the adaptive runs use)
TRAINING_SOURCE_FILES = [reference_run(p) for p in TRAINING_RUN_PATHS] + [f"{OUT}/rve_paths/{s}.h5" for s in TRAINING_RVE_SETS]
TRAINING_ROUNDS = {
    "": (TRAINING_SOURCE_FILES, NETWORKS),
    "active/": (TRAINING_SOURCE_FILES + [f"{OUT}/adaptive/{ACTIVE_LABEL}/dem_points/{p}.h5" for p in ACTIVE_PATHS],
                {n: NETWORKS[n] for n in ("sigma", "tangent")}),
}


def fem_ml_depends(wc):
    """What a FEM–ML run depends on besides the models, so that editing it re-runs the rule."""
    return {
        "specimen": config["specimen"],
        "newton": config["newton"],
        "segments": config["load_paths"][wc.path]["segments"],
        "surrogate_newton": SURROGATE["newton"],
        "anchor_initial_state": SURROGATE["anchor_initial_state"],
        "out_of_range_tolerance": SURROGATE["out_of_range_tolerance"],
    }


for _round, (_sources, _networks) in TRAINING_ROUNDS.items():
    _suffix = "_active" if _round else ""

    rule:
        name:
            f"dataset{_suffix}"
        input:
            sources=_sources,
        output:
            train=f"{OUT}/{_round}dataset/train.h5",
            heldout=f"{OUT}/{_round}dataset/heldout.h5",
        log:
            f"{OUT}/logs/surrogate/{_round}dataset.log",
        benchmark:
            f"{OUT}/benchmarks/surrogate/{_round}dataset.tsv"
        params:
            seed=config["seed"],
            train_fraction=SURROGATE["train_fraction"],
            split=SURROGATE["split"],
            history_tolerance=SURROGATE["history_tolerance"],
        threads: 1
        script:
            "../../scripts/surrogate_dataset.py"

    for _network, (_kind, _history) in _networks.items():

        rule:
            name:
                f"train_{_network}{_suffix}"
            input:
                train=f"{OUT}/{_round}dataset/train.h5",
                heldout=f"{OUT}/{_round}dataset/heldout.h5",
            output:
                model=model_file(_network, _round),
                losses=f"{OUT}/{_round}training/{_network}.csv",
                mae=f"{OUT}/{_round}training/{_network}_mae.csv",
                figure=f"{OUT}/{_round}training/{_network}_loss.png",
            log:
                f"{OUT}/logs/surrogate/{_round}train_{_network}.log",
            benchmark:
                f"{OUT}/benchmarks/surrogate/{_round}train_{_network}.tsv"
            params:
                kind=_kind,
                use_history=_history,
                settings={k: SURROGATE[k] for k in TRAINING_KEYS},
                seed=config["seed"],
            threads: SURROGATE_THREADS
            script:
                "../../scripts/surrogate_train.py"


rule fem_ml:
    input:
        sigma=model_file("sigma"),
        tangent=model_file("tangent"),
    output:
        f"{OUT}/fem_ml/{{path}}.h5",
    log:
        f"{OUT}/logs/fem_ml/{{path}}.log",
    benchmark:
        f"{OUT}/benchmarks/fem_ml/{{path}}.tsv"
    params:
        tangent=SURROGATE["tangent"],
        depends=fem_ml_depends,
        allow_partial=SURROGATE["keep_partial_runs"],
    threads: SURROGATE_THREADS
    script:
        "../../scripts/run_fem_ml.py"


rule fem_ml_nohist:
    input:
        sigma=model_file("sigma_nohist"),
        tangent=model_file("tangent_nohist"),
    output:
        f"{OUT}/fem_ml_nohist/{{path}}.h5",
    log:
        f"{OUT}/logs/fem_ml_nohist/{{path}}.log",
    benchmark:
        f"{OUT}/benchmarks/fem_ml_nohist/{{path}}.tsv"
    params:
        tangent=SURROGATE["tangent"],
        depends=fem_ml_depends,
        # the comparison without history variables may stop: it keeps its converged steps
        # (attribute completed = 0, stop_reason) and the report says where it stopped
        allow_partial=True,
    threads: SURROGATE_THREADS
    script:
        "../../scripts/run_fem_ml.py"


rule fem_ml_tangent:
    input:
        sigma=model_file("sigma"),
        tangent=model_file("tangent"),
    output:
        f"{OUT}/fem_ml_{{tangent}}/{{path}}.h5",
    log:
        f"{OUT}/logs/fem_ml_{{tangent}}/{{path}}.log",
    benchmark:
        f"{OUT}/benchmarks/fem_ml_{{tangent}}/{{path}}.tsv"
    wildcard_constraints:
        tangent="nn|autodiff",
    params:
        tangent=lambda wc: wc.tangent,
        depends=fem_ml_depends,
        # these runs compare the tangents' Newton iterations: one that stalls keeps its
        # converged steps (attribute completed = 0) instead of stopping the workflow
        allow_partial=True,
    threads: SURROGATE_THREADS
    script:
        "../../scripts/run_fem_ml.py"


METRICS_TABLES = {
    "stress_error_by_gp": f"{OUT}/tables/fem_ml_stress_error_by_gp.csv",
    "stress_error": f"{OUT}/tables/fem_ml_stress_error.csv",
    "curve_errors": f"{OUT}/tables/fem_ml_curve_errors.csv",
    "newton_iterations": f"{OUT}/tables/fem_ml_newton_iterations.csv",
    "out_of_range": f"{OUT}/tables/fem_ml_out_of_range.csv",
    "training_mae": f"{OUT}/tables/surrogate_training_mae.csv",
}


rule metrics:
    input:
        references=[reference_run(p) for p in ML_PATHS],
        fem_ml=[f"{OUT}/fem_ml/{p}.h5" for p in ML_PATHS],
        fem_ml_nohist=[f"{OUT}/fem_ml_nohist/{p}.h5" for p in ML_PATHS],
        tangent_runs=[f"{OUT}/fem_ml_{t}/{VALIDATION_PATH}.h5" for t in ("nn", "autodiff")],
        train=f"{OUT}/dataset/train.h5",
        heldout=f"{OUT}/dataset/heldout.h5",
        training_mae=[f"{OUT}/training/{n}_mae.csv" for n in NETWORKS],
    output:
        **METRICS_TABLES,
    log:
        f"{OUT}/logs/surrogate/metrics.log",
    benchmark:
        f"{OUT}/benchmarks/surrogate/metrics.tsv"
    params:
        paths=ML_PATHS,
        validation_path=VALIDATION_PATH,
        networks=list(NETWORKS),
        tangent=SURROGATE["tangent"],
    threads: 1
    script:
        "../../scripts/surrogate_metrics.py"


ALL_TARGETS += [
    *[model_file(n) for n in NETWORKS],
    *[f"{OUT}/training/{n}.csv" for n in NETWORKS],
    *[f"{OUT}/fem_ml/{p}.h5" for p in ML_PATHS],
    *[f"{OUT}/fem_ml_nohist/{p}.h5" for p in ML_PATHS],
    *METRICS_TABLES.values(),
]
