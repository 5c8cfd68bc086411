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
--screenshot serves on a free port, opens the page in headless chromium, writes a PNG and exits.

Examples:
  seeu view data/posed/clip
  seeu view out/shards/eval --checkpoint runs/cpu/checkpoints --port 8081
  seeu view out/render/gaussians.ply --save scene.viser
  seeu view out/render --screenshot docs/view.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pipelines.view import DEFAULT_HOST, DEFAULT_PORT


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", type=Path, help="posed frames, triple shards, a render directory or a .ply file")
    p.add_argument("--host", default=DEFAULT_HOST, help=f"address to serve on (default {DEFAULT_HOST})")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT}; 0: any free port)")
    p.add_argument("--checkpoint", type=Path, help="also show this checkpoint's prediction (posed frames or shards)")
    p.add_argument("--sample", default="0", help="triple shards: sample shown first, index or sample_id (default 0)")
    p.add_argument("--device", default=None, help="--checkpoint: the model's device (default cpu)")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--save", type=Path, metavar="FILE", help="write the scene as a .viser file and exit")
    out.add_argument("--screenshot", type=Path, metavar="PNG", help="screenshot the page in headless chromium and exit")


def run(args: argparse.Namespace) -> int:
    from pipelines.view import ViewConfig, build_scene, chromium_screenshot, save_scene, serve, server_url, stop_server

    cfg = ViewConfig(
        path=args.path,
        host=args.host,
        port=args.port,
        save=args.save,
        checkpoint=args.checkpoint,
        sample=args.sample,
        device=args.device,
    )
    if args.screenshot is not None:
        cfg = ViewConfig(**{**cfg.__dict__, "host": DEFAULT_HOST, "port": 0})

    def say(line: str) -> None:
        print(line, flush=True)

    server, kind = build_scene(cfg, say)
    if args.save is not None:
        size = save_scene(server, args.save)
        stop_server(server)
        say(f"wrote {args.save} ({kind}, {size} bytes)")
        return 0
    url = server_url(cfg.host, server.get_port())
    if args.screenshot is not None:
        try:
            chromium_screenshot(url, args.screenshot)
        finally:
            stop_server(server)
        say(f"wrote {args.screenshot} ({kind})")
        return 0
    say(f"seeu view: {kind} {args.path} at {url} (Ctrl-C stops)")
    serve(server, say)
    return 0
