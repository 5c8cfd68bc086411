"""Training curricula applied by the loader: the peers' context-gap warm-up.

MVSplat / pixelSplat ramp the context gap linearly from an initial to a final value over
`warm_up_steps` training steps (RE10K: 25 -> 45 over 150k steps). With triple shards the gap is fixed
per sample at build time, so the loader applies the ramp as a filter: global batch number `step`
only takes samples with `gap <= max_gap(step)`; the others at that point of the order are skipped
for the rest of the epoch (counted in the loader's `stats["skipped_curriculum"]`). Because the
filter walks the fixed epoch order (`order.plan_global_batches`), it is deterministic and resumes
exactly; "every sample exactly once" becomes "every sample exactly once or counted as skipped".
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class GapCurriculum:
    """Largest context gap allowed at a training step: linear from `initial_gap` to `final_gap`.

    `final_gap=None` means no upper limit once the warm-up is over.
    """

    initial_gap: int
    final_gap: int | None
    warm_up_steps: int

    def __post_init__(self) -> None:
        if self.warm_up_steps < 0:
            raise ValueError("warm_up_steps must be >= 0")
        if self.final_gap is not None and self.final_gap < self.initial_gap:
            raise ValueError("final_gap must be >= initial_gap")

    def max_gap(self, step: int) -> float:
        """The largest gap allowed at global step `step` (integer-floored during the ramp)."""
        final = math.inf if self.final_gap is None else self.final_gap
        if self.warm_up_steps == 0 or step >= self.warm_up_steps:
            return float(final)
        if math.isinf(final):
            return float(self.initial_gap) if step < self.warm_up_steps else math.inf
        frac = max(step, 0) / self.warm_up_steps
        return float(math.floor(self.initial_gap + (final - self.initial_gap) * frac))

    __call__ = max_gap
