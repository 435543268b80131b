"""Table 2 science without files or MLflow: metrics, height bands, the ground-effect law fit, baselines, report text
and figures."""
