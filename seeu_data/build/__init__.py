"""Build stage: triple sampling, shard rows, evaluation indices and the Ray engine."""
