# Surrogate stage: dataset -> NNσ/ND training (with and without history variables) -> FEM–ML
# runs -> accuracy tables against the reference runs.
#
#   dataset                {OUT}/dataset/train.h5, heldout.h5 from the training sources (surrogate.training_sources:
#                          reference runs of load paths, RVE-path sets), held out by trajectory class
#   train_<network>        {OUT}/models/nn_<network>.pt, {OUT}/training/<network>.csv (loss per epoch),
#                          <network>_mae.csv (final MAE per component), <network>_loss.png
#                          networks: sigma, tangent (9 inputs), sigma_nohist (6 inputs), and tangent_nohist
#                          when surrogate.tangent is nn (PLAN.networks)
#   fem_ml                 {OUT}/fem_ml/{path}.h5          tangent from config surrogate.tangent (ND an input
#                          only when that is nn)
#   fem_ml_nohist          {OUT}/fem_ml_nohist/{path}.h5   the ablation without history variables
#   fem_ml_tangent         {OUT}/fem_ml_{nn,autodiff}/{path}.h5   Newton iterations of both tangents
#   metrics                {OUT}/tables/*.csv
#   dataset_active, train_{sigma,tangent}_active   the active-learning round (adaptive.smk): the same
#                          sources plus the DEM answers of adaptive runs -> {OUT}/active/dataset, {OUT}/active/models
#   dataset_weak_zone, train_{sigma,tangent}_weak_zone   the networks of the biaxial test's weak zone
#                          (surrogate.weak_zone_sources: RVE-path sets of the weak packing) -> {OUT}/weak_zone/models
SURROGATE_THREADS = config["surrogate"]["torch_threads"]


for _round, (_sources, _networks) in PLAN.training_rounds().items():
    _suffix = "_" + _round.strip("/") if _round else ""  # _active, _weak_zone

    rule:
        name:
            f"dataset{_suffix}"
        input:
            sources=_sources,
        output:
            train=L.dataset("train", _round),
            heldout=L.dataset("heldout", _round),
        log:
            L.log(f"surrogate/{_round}dataset"),
        benchmark:
            L.benchmark(f"surrogate/{_round}dataset")
        params:
            seed=config["seed"],
            train_fraction=config["surrogate"]["train_fraction"],
            split=config["surrogate"]["split"],
            history_tolerance=config["surrogate"]["history_tolerance"],
        threads: 1
        script:
            "../../scripts/surrogate_dataset.py"

    for _network, (_kind, _history) in _networks.items():

        rule:
            name:
                f"train_{_network}{_suffix}"
            input:
                train=L.dataset("train", _round),
                heldout=L.dataset("heldout", _round),
            output:
                model=L.model(_network, _round),
                losses=L.training(f"{_network}.csv", _round),
                mae=L.training(f"{_network}_mae.csv", _round),
                figure=L.training(f"{_network}_loss.png", _round),
            log:
                L.log(f"surrogate/{_round}train_{_network}"),
            benchmark:
                L.benchmark(f"surrogate/{_round}train_{_network}")
            params:
                kind=_kind,
                use_history=_history,
                settings=PLAN.training_settings(),
                seed=config["seed"],
            threads: SURROGATE_THREADS
            priority: 0 if _round else TRAINING_PRIORITY[_network]
            script:
                "../../scripts/surrogate_train.py"


rule fem_ml:
    input:
        **PLAN.fem_ml_models(),
    output:
        L.fem_ml("{path}"),
    log:
        L.log("fem_ml/{path}"),
    benchmark:
        L.benchmark("fem_ml/{path}")
    params:
        tangent=config["surrogate"]["tangent"],
        depends=lambda wc: PLAN.fem_ml_definition(wc.path),
        allow_partial=config["surrogate"]["keep_partial_runs"],
    threads: SURROGATE_THREADS
    script:
        "../../scripts/run_fem_ml.py"


rule fem_ml_nohist:
    input:
        **PLAN.fem_ml_models(history=False),
    output:
        L.run("fem_ml_nohist", "{path}"),
    log:
        L.log("fem_ml_nohist/{path}"),
    benchmark:
        L.benchmark("fem_ml_nohist/{path}")
    params:
        tangent=config["surrogate"]["tangent"],
        depends=lambda wc: PLAN.fem_ml_definition(wc.path),
        # the comparison without history variables may stop: it keeps its converged steps
        # (attribute completed = 0, stop_reason) and the report says where it stopped
        allow_partial=True,
    threads: SURROGATE_THREADS
    script:
        "../../scripts/run_fem_ml.py"


rule fem_ml_tangent:
    input:
        sigma=L.model("sigma"),
        tangent=L.model("tangent"),
    output:
        L.run("fem_ml_{tangent}", "{path}"),
    log:
        L.log("fem_ml_{tangent}/{path}"),
    benchmark:
        L.benchmark("fem_ml_{tangent}/{path}")
    wildcard_constraints:
        tangent="nn|autodiff",
    params:
        tangent=lambda wc: wc.tangent,
        depends=lambda wc: PLAN.fem_ml_definition(wc.path),
        # these runs compare the tangents' Newton iterations: one that stalls keeps its
        # converged steps (attribute completed = 0) instead of stopping the workflow
        allow_partial=True,
    threads: SURROGATE_THREADS
    script:
        "../../scripts/run_fem_ml.py"


rule metrics:
    input:
        references=[PLAN.reference_run(p) for p in PLAN.ml_paths],
        fem_ml=[L.fem_ml(p) for p in PLAN.ml_paths],
        fem_ml_nohist=[L.run("fem_ml_nohist", p) for p in PLAN.ml_paths],
        tangent_runs=[L.run(f"fem_ml_{t}", PLAN.validation_path) for t in ("nn", "autodiff")],
        train=L.dataset("train"),
        heldout=L.dataset("heldout"),
        training_mae=[L.training(f"{n}_mae.csv") for n in PLAN.networks],
    output:
        **PLAN.metrics_tables(),
    log:
        L.log("surrogate/metrics"),
    benchmark:
        L.benchmark("surrogate/metrics")
    params:
        paths=PLAN.ml_paths,
        validation_path=PLAN.validation_path,
        networks=list(PLAN.networks),
        tangent=config["surrogate"]["tangent"],
    threads: 1
    script:
        "../../scripts/surrogate_metrics.py"
