"""What the commands do: training, sweeps, comparison, evaluation, export, MLflow tracking, the gap
finder's runs and proof, generation entry points, benchmarks and the demo. The command line
(:mod:`uavturb.cli`) parses arguments and calls one function of this package per command."""
