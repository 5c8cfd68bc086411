"""The `seeu` command line. Each subcommand lives in its own module of `pipelines/` exposing
`add_arguments(parser)` and `run(args) -> int`; modules keep heavy imports inside `run`.

Errors the user can fix (SeeUError) print one line and exit 2; `--debug` shows tracebacks.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import importlib.util
import os
import sys

from seeu_data import __version__
from seeu_data.errors import SeeUError

# name -> (module, one-line help). Commands whose module is not present are not offered.
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("pipelines.demo", "run the whole pipeline on the built-in synthetic clip"),
    "synth": ("pipelines.synth", "render the built-in synthetic clip (mp4 + ground-truth cameras)"),
    "ingest": ("pipelines.ingest", "pose a video / image folder with COLMAP SfM into posed chunks"),
    "import": ("pipelines.import_cmd", "import RE10K/ACID chunks, RE10K text, DTU, COLMAP, nerfstudio"),
    "export": ("pipelines.export_cmd", "export posed frames as pixelSplat chunks or nerfstudio"),
    "build": ("pipelines.build", "sample context-target triples into Arrow shards"),
    "index": ("pipelines.index", "generate an evaluation index for your own posed data"),
    "inspect": ("pipelines.inspect_cmd", "statistics and a contact sheet of a shards directory"),
    "validate": ("pipelines.validate", "check a dataset directory against its schema and manifest"),
    "train": ("pipelines.train", "train SeeU on triple shards"),
    "eval": ("pipelines.evaluate", "evaluate a checkpoint: PSNR/SSIM/LPIPS (and DTU depth/Chamfer)"),
    "render": ("pipelines.render", "render novel views and export a .ply from a checkpoint"),
    "ablate": ("pipelines.ablate", "run the paper's ablation configurations with equal budgets"),
    "model-info": ("pipelines.model_info", "parameter counts per module of the SeeU model"),
    "convert-checkpoint": ("pipelines.convert_checkpoint", "convert an MVSplat checkpoint into a SeeU checkpoint"),
}


def available_commands() -> dict[str, tuple[str, str]]:
    """The commands whose module is present: name -> (module, one-line help)."""
    return {k: v for k, v in COMMANDS.items() if importlib.util.find_spec(v[0]) is not None}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="seeu",
        description="SeeU toolkit: posed data from videos and datasets, triple shards, and the SeeU G-3DGS model.",
    )
    parser.add_argument("--version", action="version", version=f"seeu {__version__}")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in available_commands().items():
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


# What an OSError's errno means for the user (the system's own text follows in parentheses).
_OS_PROBLEMS = {
    errno.ENOSPC: "cannot write: no space left on the device",
    errno.EDQUOT: "cannot write: disk quota exceeded",
    errno.EROFS: "cannot write: the file system is read-only",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EISDIR: "is a directory, a file is needed here",
    errno.ENOENT: "not found",
    errno.ENAMETOOLONG: "name too long",
    errno.EMFILE: "too many open files",
    errno.EIO: "input/output error (failing disk or network file system?)",
}


def os_error_line(exc: OSError) -> str:
    """`PATH: <what> (errno text)` for an OSError (the path left out when the error names none).

    An existing file where a directory is needed (`--out` naming a file, a file in the way of a
    sub-directory: EEXIST / ENOTDIR) is reported at that file.
    """
    text = exc.strerror or str(exc)
    path = exc.filename
    what = _OS_PROBLEMS.get(exc.errno or 0, "operating-system error")
    if exc.errno in (errno.EEXIST, errno.ENOTDIR) and path is not None:
        from pathlib import Path

        p = Path(os.fsdecode(path))
        for candidate in (p, *p.parents):
            if candidate.is_file():
                path, what = candidate, "is a file, a directory is needed here"
                break
        else:
            what = "already exists" if exc.errno == errno.EEXIST else "a path component is not a directory"
    return f"{os.fsdecode(path)}: {what} ({text})" if path is not None else f"{what} ({text})"


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    debug = args.debug or os.environ.get("SEEU_DEBUG") == "1"
    try:
        return int(args._module.run(args) or 0)
    except SeeUError as exc:
        if debug:
            raise
        print(f"seeu {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # the environment (disk full, read-only, permissions, a file in the way)
        if debug:
            raise
        print(f"seeu {args.command}: error: {os_error_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"seeu {args.command}: interrupted; re-run the same command to resume", file=sys.stderr)
        return 130
    except Exception as exc:  # unexpected: still one line, with a way to see more
        if debug:
            raise
        msg = str(exc).splitlines()[0] if str(exc) else ""
        print(
            f"seeu {args.command}: internal error: {type(exc).__name__}: {msg} (re-run with --debug for the traceback)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
