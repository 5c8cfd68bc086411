"""`python -m pipelines.cli ...` runs the `seeu` command (also under torchrun: `-m pipelines.cli train ...`)."""

from pipelines.cli import entry

entry()
