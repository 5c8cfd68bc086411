"""Stage-wise pipelines users run (ingest, import, build, train, eval, render, demo) and the `seeu` CLI.
Pipelines wire seeu_data (files) to seeu_model (tensors)."""
