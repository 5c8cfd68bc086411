"""SeeU data: video decode, frame selection, SfM, camera conventions, importers/exporters,
triple sampling, Arrow shard IO, manifests and the streaming loader. Never imports seeu_model."""

__version__ = "0.1.0"
