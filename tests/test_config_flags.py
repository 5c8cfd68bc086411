"""Flags made from config declarations (seeu_data/settings.py, pipelines/cli/config_flags.py): every
flag of every `seeu` command maps to exactly one config field and back, the help states the
declared default, and the values given on the command line arrive in the config."""

from __future__ import annotations

import argparse
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path

import pytest

from pipelines.cli import build_parser
from pipelines.cli.config_flags import add_config_flags, config_from_args, settings_of
from pipelines.cli.ingest import SHARED_FLAGS
from pipelines.import_data import IMPORTERS, ImportConfig
from pipelines.ingest import IngestConfig
from seeu_data.errors import SeeUError
from seeu_data.settings import parse_dims, setting


def _subparser(parser: argparse.ArgumentParser, *names: str) -> argparse.ArgumentParser:
    for name in names:
        action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = action.choices[name]
    return parser


def _flag_dests(parser: argparse.ArgumentParser) -> dict[str, str]:
    """Each flag (or positional) of a parser -> its dest, leaving out --help."""
    out = {}
    for a in parser._actions:
        if isinstance(a, argparse._HelpAction):
            continue
        out[a.option_strings[0] if a.option_strings else a.dest] = a.dest
    return out


def _commands() -> list[tuple[tuple[str, ...], list[type], dict[str, str], tuple[str, ...], tuple[str, ...]]]:
    """(argv naming the (sub)command, its config classes, its shared flags (dest -> config field), the
    settings it leaves out (SKIP), the flags the CLI reads itself (where to write or what to read))."""
    from pipelines.ablate import AblateConfig
    from pipelines.build import BuildConfig
    from pipelines.cli import (
        ablate,
        check_cameras,
        convert_checkpoint,
        demo,
        evaluate,
        export,
        import_cmd,
        index,
        inspect_cmd,
        model_info,
        overlap,
        predict,
        render,
        synth,
        train,
        validate,
        view,
    )
    from pipelines.cli import build as build_cli
    from pipelines.convert_checkpoint import ConvertConfig
    from pipelines.demo import DemoConfig
    from pipelines.evaluate import EvalConfig
    from pipelines.index import IndexFileConfig
    from pipelines.inspect_triples import InspectConfig
    from pipelines.model_info import ModelInfoConfig
    from pipelines.overlap import OverlapConfig
    from pipelines.predict import PredictConfig
    from pipelines.render import RenderConfig
    from pipelines.train import TrainRunConfig
    from pipelines.validate import ValidateConfig
    from pipelines.view import ViewConfig
    from seeu_data.camera_check import CameraCheckConfig
    from seeu_data.synthetic import ClipConfig

    out = [
        (("ingest",), [IngestConfig], SHARED_FLAGS, (), ()),
        (("build",), [BuildConfig], build_cli.SHARED_FLAGS, build_cli.SKIP, ()),
        (("index",), [IndexFileConfig], index.SHARED_FLAGS, (), ()),
        (("validate",), [ValidateConfig], validate.SHARED_FLAGS, (), ()),
        (("overlap",), [OverlapConfig], overlap.SHARED_FLAGS, (), ()),
        (("synth",), [ClipConfig], {}, (), synth.OWN_FLAGS),
        (("demo",), [DemoConfig], demo.SHARED_FLAGS, (), ()),
        (("check-cameras",), [CameraCheckConfig], check_cameras.SHARED_FLAGS, (), ()),
        (("view",), [ViewConfig], view.SHARED_FLAGS, (), ()),
        (("predict",), [PredictConfig], predict.SHARED_FLAGS, (), ()),
        (("train",), [TrainRunConfig], train.SHARED_FLAGS, (), ()),
        (("eval",), [EvalConfig], evaluate.SHARED_FLAGS, (), ()),
        (("render",), [RenderConfig], render.SHARED_FLAGS, (), ()),
        (("ablate",), [AblateConfig], ablate.SHARED_FLAGS, (), ()),
        (("model-info",), [ModelInfoConfig], model_info.SHARED_FLAGS, (), ()),
        (("inspect",), [InspectConfig], {}, (), inspect_cmd.OWN_FLAGS),
        (("convert-checkpoint",), [ConvertConfig], convert_checkpoint.SHARED_FLAGS, (), ()),
    ]
    out += [(("import", f), [cls, ImportConfig], import_cmd.SHARED_FLAGS, (), ()) for f, (cls, _) in IMPORTERS.items()]
    formats = export._formats().items()
    out += [(("export", f), [cls], export.SHARED_FLAGS, (), export.OWN_FLAGS) for f, (cls, _) in formats]
    return out


COMMANDS = _commands()


@pytest.mark.parametrize("argv,classes,shared,skip,own", COMMANDS, ids=[" ".join(c[0]) for c in COMMANDS])
def test_every_flag_is_one_config_field_and_back(argv, classes, shared, skip, own):
    """Each flag sets one config field (a setting, or through `shared` a plain field), each setting but
    `skip` has exactly one flag, and its dest is the setting's dotted path (what config_from_args reads)."""
    parser = _subparser(build_parser(), *argv)
    settings = {s.path: s for cls in classes for s in settings_of(cls)}
    plain = {f.name for cls in classes for f in fields(cls)}
    dests = _flag_dests(parser)
    mapped: dict[str, list[str]] = {}
    for flag, dest in dests.items():
        if dest in own:
            continue
        if dest in shared:
            assert shared[dest].split(".")[0] in plain and shared[dest] not in settings, (flag, shared[dest])
            target = shared[dest]
        else:
            assert dest in settings, f"{flag} sets no config field ({dest})"
            target = dest
            s = settings[dest]
            assert flag == (dest if s.meta["positional"] else s.flag), (flag, s.flag)
        mapped.setdefault(target, []).append(flag)
    assert all(len(v) == 1 for v in mapped.values()), {k: v for k, v in mapped.items() if len(v) > 1}
    missing = [p for p in settings if p not in mapped and p not in skip]
    assert not missing, f"settings without a flag: {missing}"
    assert set(own) | set(shared) <= set(dests.values())


def test_every_command_is_generated():
    from pipelines.cli import available_commands

    assert {argv[0] for argv, *_ in COMMANDS} == set(available_commands())


def test_run_flags_arrive_in_the_stage_configs(tmp_path, capsys):
    from pipelines.ablate import AblateConfig
    from pipelines.convert_checkpoint import ConvertConfig
    from pipelines.evaluate import EvalConfig
    from pipelines.render import RenderConfig
    from pipelines.train import TrainRunConfig

    train = ["train", "--data", "d", "--out", "r"]
    cfg = config_from_args(
        TrainRunConfig, _parse([*train, "--resume", "--no-lpips", "optim.lr=1e-4", "log.every=2"]), out="r"
    )
    assert cfg.resume is True and cfg.lpips is False and cfg.overrides == ("optim.lr=1e-4", "log.every=2")
    assert cfg.val is None and cfg.max_steps is None and cfg.on_nonfinite is None
    cfg = config_from_args(TrainRunConfig, _parse([*train, "--resume", "c.pt", "--max-steps", "5"]), out="r")
    assert cfg.resume == "c.pt" and cfg.max_steps == 5 and cfg.overrides == () and cfg.lpips is True
    # an override right after --resume is an override, never the checkpoint path (#39)
    cfg = config_from_args(TrainRunConfig, _parse([*train, "--resume", "optim.lr=1e-3", "log.every=2"]), out="r")
    assert cfg.resume is True and cfg.overrides == ("optim.lr=1e-3", "log.every=2")
    cfg = config_from_args(TrainRunConfig, _parse([*train, "--resume", "seed=3"]), out="r")
    assert cfg.resume is True and cfg.overrides == ("seed=3",)
    for path in ("./seed=3", "runs/lr=1e-3/checkpoints"):  # a path of that form, written as a path
        cfg = config_from_args(TrainRunConfig, _parse([*train, "--resume", path]), out="r")
        assert cfg.resume == path and cfg.overrides == ()
    ablate_argv = ["ablate", "--config", "c", "--data", "d", "--eval", "e", "--out", "o"]
    ablate = config_from_args(AblateConfig, _parse([*ablate_argv, "--ext-data", "0=a"]), out="o")
    assert ablate.eval_data == "e" and ablate.ext_data == ((0, "a"),) and ablate.ext_ranges == (0, 45, 90)
    args = _parse([*ablate_argv, "--ext-data", "0=a", "--ext-data", "90=b", "--variants", "full, unet", "x.y=1"])
    ablate = config_from_args(AblateConfig, args, out="o")
    assert ablate.ext_data == ((0, "a"), (90, "b")) and ablate.variants == ("full", "unet")
    assert ablate.overrides == ("x.y=1",)
    for bad, line in (("--ext-data", "9"), "--ext-data '9' is not N=PATH"), (("--ext-ranges", "0,x"), "frame counts"):
        with pytest.raises(SeeUError, match=line):
            config_from_args(AblateConfig, _parse([*ablate_argv, *bad]), out="o")
    ev = config_from_args(EvalConfig, _parse(["eval", "--checkpoint", "c", "--data", "d", "--image-size", "32x48"]))
    assert ev.image_size == (32, 48) and ev.out is None and ev.batch_size == 1 and ev.lpips is True
    args = _parse(["render", "--checkpoint", "c", "--cameras", "v.json", "--out", "o"])
    render = config_from_args(RenderConfig, args, out="o")
    assert render.cameras == "v.json" and render.data is None and render.frames == 30
    conv = config_from_args(ConvertConfig, _parse(["convert-checkpoint", "mvsplat", "m.ckpt", "--out", "o"]), out="o")
    assert conv == ConvertConfig(format="mvsplat", checkpoint="m.ckpt", out="o", allow_incomplete=False)
    for argv, err in (
        (["render", "--checkpoint", "c", "--out", "o"], "one of the arguments --data --cameras is required"),
        (["render", "--checkpoint", "c", "--data", "d", "--cameras", "v", "--out", "o"], "not allowed with"),
        (["convert-checkpoint", "other", "m.ckpt", "--out", "o"], "invalid choice: 'other'"),
    ):
        with pytest.raises(SystemExit):
            _parse(argv)
        assert err in capsys.readouterr().err


def test_nested_configs_are_walked():
    assert "sfm.overlap" in _flag_dests(_subparser(build_parser(), "ingest")).values()
    build = _flag_dests(_subparser(build_parser(), "build"))
    assert build["--num-context"] == "sampling.num_context" and build["--resize"] == "image.resize"
    index = _flag_dests(_subparser(build_parser(), "index"))
    assert index["--mode"] == "generation.sampling.mode" and index["--min-overlap"] == "generation.sampling.min_overlap"


def _parse(argv: list[str]) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def test_ingest_values_arrive_in_the_nested_config(tmp_path):
    args = _parse(
        ["ingest", "a.mp4", "b", "--out", str(tmp_path), "--overlap", "7", "--no-sfm-check", "--size", "360x640"]
        + ["--target-frames", "40", "--distance-frames", "3,9", "--scale", "metric", "--known-distance", "2.5"]
        + ["--workers", "2", "--heartbeat", "0", "--force"]
    )
    cfg = config_from_args(IngestConfig, args, out=args.out, **{"run.force": args.force})
    assert cfg.inputs == ("a.mp4", "b") and cfg.out == tmp_path
    assert cfg.sfm.overlap == 7 and cfg.sfm.sfm_check is False and cfg.size == (360, 640)
    assert cfg.select.target_frames == 40 and cfg.chunks.scale.distance_frames == (3, 9)
    assert cfg.chunks.scale.scale == "metric" and cfg.chunks.scale.known_distance == 2.5
    assert cfg.run.workers == 2 and cfg.run.heartbeat_s == 0 and cfg.run.force is True
    # what was not given keeps the declared default
    assert cfg.sfm.max_features == 4096 and cfg.select.stride == 1 and cfg.sfm.random_seed == 0
    defaults = config_from_args(IngestConfig, _parse(["ingest", "x", "--out", "o"]), out=Path("o"))
    assert defaults == IngestConfig(out=Path("o"), inputs=("x",))


def test_import_values_arrive_in_the_format_config(tmp_path):
    args = _parse(
        ["import", "dtu", str(tmp_path), "--out", str(tmp_path / "o"), "--scans", "1,8", "--max-pixels", "1e6"]
        + ["--verify-decode", "--strict"]
    )
    source = config_from_args(args.source_cls, args)
    assert source.scans == (1, 8) and source.max_pixels == 1_000_000 and source.verify_decode is True
    assert source.lighting == 3 and source.root == tmp_path
    cfg = config_from_args(ImportConfig, args, source=source, out=args.out)
    assert cfg.strict is True and cfg.source is source
    args = _parse(["import", "nerfstudio", "t.json", "--out", "o", "--keep-applied-transform", "--no-undistort"])
    source = config_from_args(args.source_cls, args)
    assert source.undo_applied_transform is False and source.undistort is False and source.skip_missing is False


def test_help_states_the_declared_default():
    for cls, skip in {(c, skip) for _, classes, _, skip, _ in COMMANDS for c in classes}:
        parser = argparse.ArgumentParser()
        for s in add_config_flags(parser, cls, skip=skip):
            default = s.field.default
            help_text = next(a.help for a in parser._actions if s.flag in a.option_strings or a.dest == s.path)
            if s.kind is not bool and default not in (MISSING, None, ()):
                assert "default" in help_text, (cls.__name__, s.flag, help_text)
                if isinstance(default, tuple):
                    shown = ("x" if s.meta["metavar"] == "HxW" else ",").join(map(str, default))
                else:
                    shown = str(default)
                if "default:" not in help_text:  # "default: ..." says what a sentinel (-1, auto) means
                    assert f"default {shown}" in help_text, (s.flag, help_text)


def test_build_and_index_values_arrive(tmp_path):
    from pipelines.build import BuildConfig
    from pipelines.cli.build import run as build_run
    from pipelines.cli.index import run as index_run
    from seeu_data.build.sampling import SamplingConfig

    args = _parse(
        [
            "build",
            "a",
            "b",
            "--out",
            str(tmp_path),
            "--mode",
            "extrap",
            "-V",
            "3",
            "--gap-min",
            "4",
            "--resize",
            "32x48",
        ]
        + ["--shard-size", "64MiB", "--near", "1", "--far", "100", "--fsync", "--max-pixels", "1e6"]
    )
    cfg = config_from_args(BuildConfig, args, **{"sampling.mode": "extrap", "out": args.out, "fsync": args.fsync})
    assert cfg.inputs == ("a", "b") and cfg.mode == "extrap" and cfg.sampling.num_context == 3
    assert cfg.sampling.gap_min == 4 and cfg.image.resize == (32, 48) and cfg.shard_bytes == 64 << 20
    assert cfg.near_far == (1.0, 100.0) and cfg.fsync is True and cfg.workers is None
    defaults = config_from_args(BuildConfig, _parse(["build", "x", "--out", "o"]), out="o")
    assert defaults == BuildConfig(inputs=("x",), out="o") and defaults.shard_bytes == 128_000_000
    assert defaults.sampling == SamplingConfig()
    with pytest.raises(SeeUError, match="invalid sampling options: gap_max must be >= gap_min"):
        build_run(_parse(["build", "x", "--out", str(tmp_path / "o"), "--gap-min", "9", "--gap-max", "5"]))
    with pytest.raises(SeeUError, match="invalid sampling options"):
        index_run(_parse(["index", "x", "--out", str(tmp_path / "i.json"), "--gap-min", "9", "--gap-max", "5"]))


def test_sizes_are_hxw_and_exclusive_flags(capsys):
    from pipelines.demo import DemoConfig
    from pipelines.predict import PredictConfig
    from pipelines.view import ViewConfig
    from seeu_data.exporters.pixelsplat import PixelSplatExportConfig
    from seeu_data.synthetic import ClipConfig

    clip = config_from_args(ClipConfig, _parse(["synth", "--out", "o", "--size", "360x640", "--frames", "5"]))
    assert clip.size == (360, 640) and (clip.height, clip.width) == (360, 640) and clip.n_frames == 5
    demo = config_from_args(DemoConfig, _parse(["demo", "--size", "180x320", "--image-size", "32"]))
    assert demo.size == (180, 320) and demo.image_size == (32, 32) and demo.out == Path("out/demo")
    with pytest.raises(SeeUError, match="--size 100000 is over the limit 4096"):
        config_from_args(DemoConfig, _parse(["demo", "--size", "100000x100000"]))
    args = _parse(["export", "pixelsplat", "d", "--out", "o", "--resize", "none", "--chunk-mb", "0.5"])
    cfg = config_from_args(args.export_cls, args, out=args.out)
    assert isinstance(cfg, PixelSplatExportConfig) and cfg.resize is None and cfg.chunk_bytes == 500_000
    assert config_from_args(args.export_cls, _parse(["export", "pixelsplat", "d", "--out", "o"]), out="o").resize
    predict = config_from_args(
        PredictConfig, _parse(["predict", "s", "--checkpoint", "c", "--context", "3,9", "--out", "o"]), out="o"
    )
    assert predict.context == (3, 9) and predict.auto_context is False
    view = config_from_args(ViewConfig, _parse(["view", "p", "--screenshot", "x.png", "--port", "0"]))
    assert view.screenshot == Path("x.png") and view.port == 0 and view.save is None
    for argv in (
        ["predict", "s", "--checkpoint", "c", "--context", "1,2", "--auto-context"],
        ["view", "p", "--save", "a", "--screenshot", "b"],
    ):
        with pytest.raises(SystemExit):
            _parse(argv)
        assert "not allowed with argument" in capsys.readouterr().err


@dataclass(frozen=True)
class _Inner:
    size: tuple[int, int] | None = setting(None, "HxW (default: none)", parse=parse_dims)
    on: bool = setting(True, "turn it off")


@dataclass(frozen=True)
class _Outer:
    name: str = setting(help="required name")
    count: int = setting(3, "how many")
    constant: float = 0.5  # internal: no flag
    inner: _Inner = field(default_factory=_Inner)


@dataclass(frozen=True)
class _Clash:
    size: int = setting(1, "a second --size")
    inner: _Inner = field(default_factory=_Inner)


def test_the_generator_on_a_small_config():
    parser = argparse.ArgumentParser(exit_on_error=False)
    added = add_config_flags(parser, _Outer)
    assert [s.flag for s in added] == ["--name", "--count", "--size", "--no-on"]
    args = parser.parse_args(["--name", "x", "--size", "4x6", "--no-on"])
    assert config_from_args(_Outer, args) == _Outer(name="x", inner=_Inner(size=(4, 6), on=False))
    with pytest.raises(SeeUError, match="--size"):  # a parser's error names the flag
        config_from_args(_Outer, parser.parse_args(["--name", "x", "--size", "big"]))
    with pytest.raises(SystemExit):  # required, as declared
        parser.parse_args([])
    assert "(default 3)" in parser.format_help()
    with pytest.raises(ValueError, match="both want"):
        add_config_flags(argparse.ArgumentParser(), _Clash)
