"""Training: typed config, LR schedule, checkpoints, distributed set-up and the training loop."""
