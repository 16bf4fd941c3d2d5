"""Neural surrogate of the Gauss-point response: dataset, NNσ/ND networks, training, material-point set.
(FEM–ML runs compose the solver with it one layer up: ``drivers.fem_ml``.)

    dataset   reference run (step, gp) -> train/held-out sets split by Gauss point, min–max scaling
    models    the MLPs with their scaling, feature/target names and config in one file
    training  seeded, deterministic mini-batch training; loss history and per-component MAE
    material  SurrogateMaterial: the networks as a material-point set for the FEM solver
"""
