"""Our loader in the peers' setting: `batch_format="pixelsplat"` against MVSplat's own loader's batch
(tests/fixtures/pixelsplat_batch/, made by its make_fixture.py with MVSplat's code), and
`seeu_data.lightning.TripleDataModule` in a real Lightning `Trainer.fit` on CPU (2 steps, then a resume
from its checkpoint)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from seeu_data.loader import make_loader

FIXTURE = Path(__file__).resolve().parent / "fixtures" / "pixelsplat_batch"
PEER_VIEW_KEYS = ["extrinsics", "intrinsics", "image", "near", "far", "index"]


@pytest.mark.parametrize("image_dtype", ["uint8", "float32"])
def test_pixelsplat_batch_equals_mvsplat(image_dtype):
    theirs = torch.load(FIXTURE / "mvsplat_batch.pt", weights_only=True)
    loader = make_loader(
        FIXTURE / "triples", 2, shuffle=False, image_hw=(32, 48), image_dtype=image_dtype, batch_format="pixelsplat"
    )
    (ours,) = list(loader)
    assert list(ours) == ["context", "target", "scene", "is_padding"]
    assert ours["scene"] == theirs["scene"] == ["syn0", "syn1"]
    assert ours["is_padding"].tolist() == [False, False]
    for side in ("context", "target"):
        assert list(ours[side]) == list(theirs[side]) == PEER_VIEW_KEYS
        for key in PEER_VIEW_KEYS:
            a, b = ours[side][key], theirs[side][key]
            assert (a.dtype, a.shape) == (b.dtype, b.shape), (side, key)
            torch.testing.assert_close(a, b, rtol=0, atol=1e-6, msg=f"{side} {key}")
    assert ours["target"]["image"].shape == (2, 3, 3, 32, 48)


def test_batch_format_is_checked():
    with pytest.raises(ValueError, match="batch_format"):
        make_loader(FIXTURE / "triples", 1, batch_format="re10k")


def _fit(triples: Path, root: Path, max_steps: int, ckpt_path: Path | None = None):
    """`Trainer.fit` of a tiny model on CPU, validating at each epoch's end; returns (trainer, the
    (scene, context index) of each training step's batch, the sample count of each validation pass)."""
    import lightning as L

    from seeu_data.lightning import TripleDataModule

    class Tiny(L.LightningModule):
        def __init__(self):
            super().__init__()
            self.gain = torch.nn.Parameter(torch.ones(3))
            self.seen: list[tuple] = []
            self.val: list[int] = []

        def training_step(self, batch, batch_idx):
            ctx, tgt = batch["context"], batch["target"]
            assert ctx["image"].dtype == torch.float32 and ctx["extrinsics"].shape[-2:] == (4, 4)
            self.seen.append((tuple(batch["scene"]), tuple(ctx["index"].flatten().tolist())))
            pred = ctx["image"].mean(1) * self.gain[:, None, None]
            return torch.nn.functional.mse_loss(pred, tgt["image"][:, 0])

        def validation_step(self, batch, batch_idx):
            if not self.trainer.sanity_checking:
                self.val.append(int((~batch["is_padding"]).sum()))

        def configure_optimizers(self):
            return torch.optim.SGD(self.parameters(), lr=0.1)

    data = TripleDataModule(
        triples, 1, val=triples, val_batch_size=3, image_hw=(32, 32), batch_format="pixelsplat", seed=3
    )
    model = Tiny()
    trainer = L.Trainer(
        max_steps=max_steps,
        accelerator="cpu",
        devices=1,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        default_root_dir=root,
    )
    trainer.fit(model, datamodule=data, ckpt_path=ckpt_path)
    return trainer, model.seen, model.val


def test_lightning_trainer_fit_and_resume(workspace, tmp_path):
    """2 steps; resumed to the end of the epoch (4 samples, batch 1: validation runs, the whole set after the
    sanity check's pass); resumed again from that end into the next epoch: every step gets the batch the
    loader gives on its own, none repeated or skipped."""
    triples = workspace["triples"]
    loader = make_loader(triples, 1, image_hw=(32, 32), batch_format="pixelsplat", seed=3)
    expected = [(tuple(b["scene"]), tuple(b["context"]["index"].flatten().tolist())) for _ in range(2) for b in loader]
    trainer, seen, val = _fit(triples, tmp_path, max_steps=2)
    assert trainer.global_step == 2 and seen == expected[:2] and val == []
    trainer.save_checkpoint(tmp_path / "two.ckpt")
    state = torch.load(tmp_path / "two.ckpt", weights_only=False)["loops"]["fit_loop"]["state_dict"]
    assert [(s["epoch"], s["samples_seen"], s["step"]) for s in state["combined_loader"]] == [(0, 2, 2)]
    trainer, seen, val = _fit(triples, tmp_path, max_steps=4, ckpt_path=tmp_path / "two.ckpt")
    assert trainer.global_step == 4 and seen == expected[2:4] and val == [3, 1]
    trainer.save_checkpoint(tmp_path / "four.ckpt")
    trainer, seen, val = _fit(triples, tmp_path, max_steps=5, ckpt_path=tmp_path / "four.ckpt")
    assert trainer.global_step == 5 and seen == expected[4:5]
