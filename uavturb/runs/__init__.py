"""The run platform: configuration schema, MLflow store, training, sweeps, executors, accelerators, Table 1."""
