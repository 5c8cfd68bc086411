"""MVSplat's encoder inside SeeU (``encoder: "mvsplat"`` in the model config), its checkpoint key map,
and the converter of MVSplat's Lightning checkpoints (`seeu convert-checkpoint mvsplat`)."""
