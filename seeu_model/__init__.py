"""SeeU model: encoder, cost volume, CEA, Conditional Gaussian Transformer, decoder, rasterizer
backends, losses, metrics, training and evaluation loops. Never parses files: pipelines do."""
