"""Exporters: posed-frames directories -> the formats peer tools read (`seeu export FORMAT ...`).

`pixelsplat`: chunks + index.json that the pixelSplat / MVSplat / DepthSplat loaders read unchanged.
`nerfstudio`: one folder per scene with the image files and a `transforms.json`.
"""
