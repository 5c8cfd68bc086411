"""The effective batch of a run: samples per optimizer step = per-device batch x devices x accumulation.

A preset is written for one device (the paper trains on one GPU with batch 8): its effective batch is
``data.batch_size x optim.accumulate``. On G devices a run's effective batch is G times that, unless
`keep_effective=True` (`seeu train --keep-effective-batch`): then the run keeps the preset's effective
batch, and with it the meaning of its learning rate and schedule, by splitting it over the devices and
gradient-accumulation steps, never putting more samples on one device at once than ``data.batch_size``:

```
preset batch 8, accumulate 1 (E = 8):  1 device -> 8 x 1 x 1;  2 devices -> 4 x 2 x 1;  8 devices -> 1 x 8 x 1
preset batch 2, accumulate 4 (E = 8):  1 device -> 2 x 1 x 4;  2 devices -> 2 x 2 x 2;  3 devices -> error
```
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from seeu_data.errors import SeeUError


@dataclass(frozen=True)
class BatchPlan:
    """per_device: samples per device and micro-batch; devices: processes (world size); accumulate:
    micro-batches per optimizer step."""

    per_device: int
    devices: int
    accumulate: int

    @property
    def effective(self) -> int:
        """Samples per optimizer step over all devices."""
        return self.per_device * self.devices * self.accumulate

    def describe(self) -> str:
        steps = "step" if self.accumulate == 1 else "steps"
        devices = "device" if self.devices == 1 else "devices"
        return (
            f"effective batch {self.effective} = {self.per_device} per device x {self.devices} {devices} "
            f"x {self.accumulate} accumulation {steps}"
        )

    def to_dict(self) -> dict:
        return {**asdict(self), "effective": self.effective}


def plan_batches(batch_size: int, accumulate: int, devices: int, keep_effective: bool = False) -> BatchPlan:
    """The run's batches for a config's `batch_size` (per device) and `accumulate` on `devices` processes.

    keep_effective: keep ``batch_size x accumulate`` (the preset's effective batch, for one device) on
    any number of devices: the fewest accumulation steps whose per-device batch is at most `batch_size`.
    Raises SeeUError when that batch cannot be split evenly over the devices.

    >>> plan_batches(8, 1, 2, keep_effective=True)
    BatchPlan(per_device=4, devices=2, accumulate=1)
    >>> plan_batches(2, 4, 2, keep_effective=True)
    BatchPlan(per_device=2, devices=2, accumulate=2)
    """
    if not keep_effective:
        return BatchPlan(batch_size, devices, accumulate)
    effective = batch_size * accumulate
    if effective % devices:
        raise SeeUError(
            f"--keep-effective-batch: the config's effective batch {effective} (data.batch_size {batch_size} x "
            f"optim.accumulate {accumulate}) cannot be split evenly over {devices} devices; use a device count "
            f"that divides it, or set data.batch_size / optim.accumulate for this device count"
        )
    per_rank = effective // devices
    steps = next(a for a in range(1, per_rank + 1) if per_rank % a == 0 and per_rank // a <= batch_size)
    return BatchPlan(per_rank // steps, devices, steps)
