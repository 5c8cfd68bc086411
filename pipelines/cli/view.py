"""See what you made: posed frames, triple shards or Gaussians in the browser (viser).

PATH (its kind detected):
  posed frames (seeu ingest / import output; also transforms.json, a COLMAP model, pixelSplat
      chunks): camera frustums with thumbnails, the trajectory, the SfM points ingest kept; a scene
      dropdown and a frame slider
  triple shards (seeu build output): one triple, context frustums blue, targets orange, the context
      gap and target offsets; next / previous buttons
  a render directory (seeu render / demo output: gaussians.ply + cameras.json) or a .ply file: the
      Gaussians (or a point cloud) with the cameras
With --checkpoint (posed frames or shards) the model's prediction is drawn too, and your current
view is rendered live by SeeU's rasterizer (small, on the CPU) in the side panel.

Serves until Ctrl-C and prints the URL. Large scenes are subsampled with a printed note.
--save writes the scene as first drawn (the first scene / the chosen sample; GUI controls are not
part of it) as a .viser file for viser's offline player, and exits without serving.
--screenshot serves on a free port, opens the page in headless chromium, writes a PNG once the
scene is drawn (thumbnails, panel) and exits.

Examples:
  seeu view data/posed/clip
  seeu view out/shards/eval --checkpoint runs/cpu/checkpoints --port 8081
  seeu view out/render/gaussians.ply --save scene.viser
  seeu view out/render --screenshot docs/view.png
"""

from __future__ import annotations

import argparse
from dataclasses import replace

from pipelines.cli.config_flags import add_config_flags, config_from_args

SHARED_FLAGS: dict[str, str] = {}  # every flag comes from a `setting` of ViewConfig


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.view import ViewConfig

    add_config_flags(p, ViewConfig)


def run(args: argparse.Namespace) -> int:
    from pipelines.view import (
        DEFAULT_HOST,
        ViewConfig,
        build_scene,
        save_scene,
        screenshot_scene,
        serve,
        server_url,
        stop_server,
    )

    cfg = config_from_args(ViewConfig, args)
    if cfg.screenshot is not None:
        cfg = replace(cfg, host=DEFAULT_HOST, port=0)

    def say(line: str) -> None:
        print(line, flush=True)

    server, kind = build_scene(cfg, say)
    if cfg.save is not None:
        size = save_scene(server, cfg.save)
        stop_server(server)
        say(f"wrote {cfg.save} ({kind}, {size} bytes)")
        return 0
    if cfg.screenshot is not None:
        try:
            screenshot_scene(server, cfg.screenshot)
        finally:
            stop_server(server)
        say(f"wrote {cfg.screenshot} ({kind})")
        return 0
    url = server_url(cfg.host, server.get_port())
    say(f"seeu view: {kind} {cfg.path} at {url} (Ctrl-C stops)")
    serve(server, say)
    return 0
