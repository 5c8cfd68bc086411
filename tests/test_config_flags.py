"""Flags made from config declarations (seeu_data/settings.py, pipelines/cli/config_flags.py): every
flag of `seeu ingest` and `seeu import` maps to exactly one config field and back, the help states the
declared default, and the values given on the command line arrive in the config."""

from __future__ import annotations

import argparse
from dataclasses import MISSING, dataclass, field
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


def _check_one_to_one(parser: argparse.ArgumentParser, cls: type, shared: dict[str, str]) -> None:
    dests = _flag_dests(parser)
    settings = {s.path: s for s in settings_of(cls)}
    mapped = {}
    for flag, dest in dests.items():
        target = shared.get(dest, dest)
        assert target in settings or target in shared.values(), f"{flag} sets no config field ({dest})"
        mapped.setdefault(target, []).append(flag)
    assert all(len(v) == 1 for v in mapped.values()), {k: v for k, v in mapped.items() if len(v) > 1}
    missing = [p for p in settings if p not in mapped]
    assert not missing, f"settings without a flag: {missing}"


def test_every_ingest_flag_is_one_config_field_and_back():
    parser = _subparser(build_parser(), "ingest")
    _check_one_to_one(parser, IngestConfig, SHARED_FLAGS)
    assert "sfm.overlap" in _flag_dests(parser).values()  # nested configs are walked


@pytest.mark.parametrize("fmt", sorted(IMPORTERS))
def test_every_import_flag_is_one_config_field_and_back(fmt):
    source_cls, _ = IMPORTERS[fmt]
    parser = _subparser(build_parser(), "import", fmt)
    shared = {"out": "out", "progress": "progress", "fsync": "fsync", "strict": "strict"}
    dests = {d for d in _flag_dests(parser).values() if d not in shared}
    assert dests == {s.path for s in settings_of(source_cls)}
    assert {s.path for s in settings_of(ImportConfig)} == {"strict"}


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
    assert cfg.sfm.max_features == 8192 and cfg.select.stride == 1 and cfg.sfm.random_seed == 0
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
    for cls in [IngestConfig] + [c for c, _ in IMPORTERS.values()]:
        parser = argparse.ArgumentParser()
        for s in add_config_flags(parser, cls):
            default = s.field.default
            help_text = next(a.help for a in parser._actions if s.flag in a.option_strings or a.dest == s.path)
            if s.kind is not bool and default not in (MISSING, None, ()):
                assert "default" in help_text, (cls.__name__, s.flag, help_text)
                if "default:" not in help_text and not isinstance(default, tuple):
                    assert f"default {default}" in help_text or "default 1/200" in help_text, (s.flag, help_text)


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
