"""Stage-wise pipelines users run, as library functions with typed configs (`pipelines/<stage>.py`:
ingest, import_data, train, evaluate, render, demo, ablate, ...), and the `seeu` CLI on top of them
(`pipelines/cli/`). Pipelines wire seeu_data (files) to seeu_model (tensors)."""
