"""The `seeu` command line: a thin layer over the stage libraries of `pipelines/` and `seeu_data/`.

Each subcommand is a module of `pipelines.cli` exposing `add_arguments(parser)` (its flags; the ones
many commands share come from `pipelines.cli.options`) and `run(args) -> int`, which only turns the
flags into the stage's typed config, calls the stage function and prints its summary. Modules keep
heavy imports inside `run`. The module docstring is the command's `--help` description.

Errors the user can fix (SeeUError) print one line and exit 2; `--debug` shows tracebacks. Ctrl-C
(SIGINT) and SIGTERM end the command's child processes and print one line: exit 130 / 143. The
SIGTERM handler is installed first thing, before the commands' modules are imported; a SIGTERM that
a library swallowed still ends the command with that line and 143 (`interrupts.terminated`).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os
import sys

from seeu_data import __version__
from seeu_data.errors import SeeUError, os_error_line
from seeu_data.interrupts import Terminated, sigterm_raises, terminated, worker_death

# name -> (module, one-line help). Commands whose module is not present are not offered.
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("pipelines.cli.demo", "run the whole pipeline on the built-in synthetic clip"),
    "synth": ("pipelines.cli.synth", "render the built-in synthetic clip (mp4 + ground-truth cameras)"),
    "ingest": ("pipelines.cli.ingest", "pose a video / image folder with COLMAP SfM into posed chunks"),
    "import": ("pipelines.cli.import_cmd", "import RE10K/ACID chunks, RE10K text, DTU, COLMAP, nerfstudio"),
    "export": ("pipelines.cli.export", "export posed frames as pixelSplat chunks or nerfstudio"),
    "build": ("pipelines.cli.build", "sample context-target triples into Arrow shards"),
    "index": ("pipelines.cli.index", "generate an evaluation index for your own posed data"),
    "inspect": ("pipelines.cli.inspect_cmd", "statistics and a contact sheet of a shards directory"),
    "validate": ("pipelines.cli.validate", "check a dataset directory against its schema and manifest"),
    "overlap": ("pipelines.cli.overlap", "add the view-overlap table to posed frames written without one"),
    "check-cameras": ("pipelines.cli.check_cameras", "check that a dataset's cameras agree with its images (epipolar)"),
    "view": ("pipelines.cli.view", "look at posed frames, triple shards or Gaussians in the browser (viser)"),
    "train": ("pipelines.cli.train", "train SeeU on triple shards"),
    "eval": ("pipelines.cli.evaluate", "evaluate a checkpoint: PSNR/SSIM/LPIPS (and DTU depth/Chamfer)"),
    "render": ("pipelines.cli.render", "render novel views and export a .ply from a checkpoint"),
    "predict": ("pipelines.cli.predict", "a checkpoint's Gaussians and novel views of your posed scene"),
    "ablate": ("pipelines.cli.ablate", "run the paper's ablation configurations with equal budgets"),
    "model-info": ("pipelines.cli.model_info", "parameter counts per module of the SeeU model"),
    "convert-checkpoint": ("pipelines.cli.convert_checkpoint", "convert an MVSplat checkpoint into a SeeU checkpoint"),
}


def available_commands() -> dict[str, tuple[str, str]]:
    """The commands whose module is present: name -> (module, one-line help)."""
    return {k: v for k, v in COMMANDS.items() if importlib.util.find_spec(v[0]) is not None}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The `seeu` parser; with `only`, the other commands are listed (name and help) but their modules are
    not imported, which keeps a command's start short."""
    parser = argparse.ArgumentParser(
        prog="seeu",
        description="SeeU toolkit: posed data from videos and datasets, triple shards, and the SeeU G-3DGS model.",
    )
    parser.add_argument("--version", action="version", version=f"seeu {__version__}")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in available_commands().items():
        if only is not None and name != only:
            sub.add_parser(name, help=help_text)
            continue
        mod = importlib.import_module(module)
        p = sub.add_parser(
            name,
            help=help_text,
            description=(mod.__doc__ or help_text).strip(),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        mod.add_arguments(p)
        p.set_defaults(_module=mod)
    return parser


def main(argv: list[str] | None = None) -> int:
    # SIGTERM unwinds like Ctrl-C (children are ended, the outputs stay resumable), from the first
    # moment: before the commands' modules and their libraries are imported
    with sigterm_raises():
        try:
            words = sys.argv[1:] if argv is None else argv
            parser = build_parser(only=next((w for w in words if not w.startswith("-")), ""))
            args = parser.parse_args(argv)
        except Terminated:
            return _interrupted("seeu", "SIGTERM", 143)
        if not getattr(args, "command", None):
            parser.print_help()
            return 2
        code = _run(args)
    if terminated() and code != 143:  # a library swallowed the Terminated it raised: the command still ends so
        return _interrupted(f"seeu {args.command}", "SIGTERM", 143)
    return code


def entry() -> None:
    """The `seeu` console script and `python -m pipelines.cli`: `main`'s status as the process's exit status.
    Ended by SIGTERM (143), the process exits at once once its one line is out, without the interpreter's
    shutdown: the command has unwound (its children ended, its outputs resumable), and the shutdown's joins of
    a library's threads once hung a SIGTERM'd `seeu build` for 120 s in CI after its line was printed."""
    code = main()
    if code == 143:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


def _interrupted(who: str, signal_name: str, code: int) -> int:
    print(f"{who}: interrupted ({signal_name}); re-run the same command to resume", file=sys.stderr)
    return code


def _run(args: argparse.Namespace) -> int:
    """The command's `run`, its errors and interruptions as one line and an exit status."""
    who = f"seeu {args.command}"
    debug = args.debug or os.environ.get("SEEU_DEBUG") == "1"
    try:
        return int(args._module.run(args) or 0)
    except KeyboardInterrupt:
        return _interrupted(who, "SIGINT", 130)
    except Terminated:
        return _interrupted(who, "SIGTERM", 143)
    except Exception as exc:
        if terminated():  # the consequence of a SIGTERM a library swallowed (e.g. a half-imported module)
            return _interrupted(who, "SIGTERM", 143)
        if debug:
            raise
        if isinstance(exc, SeeUError):
            print(f"{who}: error: {exc}", file=sys.stderr)
            return 2
        if isinstance(exc, OSError):  # the environment (disk full, read-only, permissions, a file in the way)
            print(f"{who}: error: {os_error_line(exc)}", file=sys.stderr)
            return 2
        died = worker_death(exc)  # a loader worker killed (out of memory, kill -9): PyTorch's RuntimeError
        if died is not None:
            print(f"{who}: error: {died}", file=sys.stderr)
            return 2
        msg = str(exc).splitlines()[0] if str(exc) else ""  # unexpected: still one line, with a way to see more
        print(
            f"{who}: internal error: {type(exc).__name__}: {msg} (re-run with --debug for the traceback)",
            file=sys.stderr,
        )
        return 1
