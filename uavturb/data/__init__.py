"""Datasets: simulator shards and pre-training pairs on disk (:mod:`uavturb.io.shards`),
synthetic data with known answers (:mod:`uavturb.data.synthetic`) and Lightning DataModules
(:mod:`uavturb.data.datamodules`)."""
