"""Our streaming loader inside a Lightning `Trainer`: `TripleDataModule` (optional extra `seeu[lightning]`).

```
from seeu_data.lightning import TripleDataModule
data = TripleDataModule("out/triples", batch_size=14, image_hw=(256, 256), batch_format="pixelsplat")
lightning.Trainer(max_steps=300_000).fit(model, datamodule=data)
```

The only seeu_data module that imports `lightning` (nothing else imports this one). The loaders are
`StreamingLoader`s (`seeu_data.loader`), made when the Trainer asks for them, i.e. after it has set up
torch.distributed, so each rank reads its own part. Lightning needs nothing special for them:

* resume: a `StreamingLoader` has `state_dict()` / `load_state_dict()`, which Lightning's fit loop
  saves in its checkpoints and restores (position within the epoch included, exactly: the loader has
  a length, so Lightning fetches no batch ahead of the step);
* epochs: the loader moves to the next epoch by itself when one ends (a new order from the seed);
* device: `transfer_batch_to_device` is `batch_to_device`, so the default uint8 images cross to the
  device at a quarter of the bytes and become float32 in [0, 1] there (pixelSplat-layout batches are
  float32 already).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import lightning as L
import torch

from seeu_data.loader import StreamingLoader, batch_to_device, make_loader


class EveryPassFromStart:
    """A validation loader: every pass (and its length) starts at the beginning of epoch 0, so each
    validation sees the whole set in the same order, whatever an earlier pass (Lightning's sanity check:
    2 batches) left off. Not stateful: Lightning's checkpoints keep only the training loader's position."""

    def __init__(self, loader: StreamingLoader):
        self.loader = loader

    def _rewind(self) -> None:
        self.loader.load_state_dict({"epoch": 0, "samples_seen": 0, "step": 0})

    def __len__(self) -> int:
        self._rewind()
        return len(self.loader)

    def __iter__(self) -> Iterator[Any]:
        self._rewind()
        return iter(self.loader)


class TripleDataModule(L.LightningDataModule):
    """Training (and optionally validation) batches from triple shards (local directory or object-storage URL).

    `batch_size`: per rank; `num_workers`: DataLoader worker processes per rank; `config`: the other
    `seeu_data.loader.LoaderConfig` fields (`image_hw`, `seed`, `flip_p`, `remainder`, `image_dtype`,
    `batch_format`, ...), used for both loaders, except that validation never shuffles nor flips and
    starts from the beginning on every pass (`EveryPassFromStart`).
    """

    def __init__(
        self,
        train: str | Path,
        batch_size: int,
        *,
        val: str | Path | None = None,
        val_batch_size: int | None = None,
        num_workers: int = 0,
        pin_memory: bool = False,
        **config: Any,
    ):
        super().__init__()
        self.train_source, self.val_source = train, val
        self.batch_size = int(batch_size)
        self.val_batch_size = int(val_batch_size or batch_size)
        self.num_workers = int(num_workers)
        self.pin_memory = pin_memory
        self.config = config
        if val is None:  # Lightning then sees no validation loader (and warns about no validation_step)
            self.val_dataloader = super().val_dataloader  # type: ignore[method-assign]

    def train_dataloader(self) -> StreamingLoader:
        return make_loader(
            self.train_source,
            self.batch_size,
            num_workers=self.num_workers,
            pin_memory=self.pin_memory,
            **self.config,
        )

    def val_dataloader(self) -> EveryPassFromStart:
        assert self.val_source is not None
        config = {**self.config, "shuffle": False, "flip_p": 0.0}
        return EveryPassFromStart(
            make_loader(
                self.val_source, self.val_batch_size, num_workers=self.num_workers, pin_memory=self.pin_memory, **config
            )
        )

    def transfer_batch_to_device(self, batch: Any, device: torch.device, dataloader_idx: int) -> Any:
        return batch_to_device(batch, device)
