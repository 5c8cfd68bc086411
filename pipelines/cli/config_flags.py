"""Command-line flags generated from a stage config's `setting(...)` fields (seeu_data/settings.py),
and the config read back from the parsed flags: each setting is declared once, in its config.

    add_config_flags(parser, IngestConfig)          # every setting of IngestConfig and its nested configs
    cfg = config_from_args(IngestConfig, args, out=args.out, progress=progress_wanted(args))

Rules: `--<name-with-dashes>` (or the setting's `flag`); an int, float, str or Path value is converted
by argparse, any other by the setting's `parse`; a bool whose default is False is a switch, one whose
default is True a `--no-<name>` switch that sets it False; a `many` flag may be repeated (a tuple of
its parsed values), a `const` one given without a value; choices and the default come into the help
from the declaration (unless the help already says what the default is). Nested configs' settings are
flattened into one flag namespace (a name used twice is an error when the parser is built).

A `const` flag's value is never a KEY=VALUE override (a dotted name, `=`, anything): argparse hands
`--resume optim.lr=1e-3` the override as the checkpoint path, so `config_from_args` gives the flag
its `const` (`--resume` alone) and the override to the command's KEY=VALUE positionals, ahead of the
others. A checkpoint whose path has that form is written with its directory (`./seed=3`).
"""

from __future__ import annotations

import argparse
import re
import types
import typing
from dataclasses import MISSING, Field, dataclass, fields, is_dataclass
from pathlib import Path
from typing import Any

from pipelines.cli.options import Flags


@dataclass(frozen=True)
class Setting:
    """One flag of a config: `path` the dotted field path ("sfm.overlap"), `flag` ("--overlap" or the
    positional's name), `field` the dataclass field, `kind` its value type (int, float, str, Path, bool,
    or None: parsed by the setting's `parse`)."""

    path: str
    flag: str
    field: Field
    kind: type | None

    @property
    def meta(self) -> Any:
        return self.field.metadata


def _value_type(hint: Any) -> tuple[type | None, bool]:
    """(the plain type of an annotation, whether None is allowed); None: not a plain int/float/str/Path/bool."""
    optional = False
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        optional = len(args) < len(typing.get_args(hint))
        hint = args[0] if len(args) == 1 else None
    if typing.get_origin(hint) is tuple:
        return None, optional
    return (hint if hint in (int, float, str, Path, bool) else None), optional


def settings_of(cls: type, prefix: str = "") -> list[Setting]:
    """Every `setting(...)` field of the dataclass `cls` and of its nested configs, in declaration order."""
    hints = typing.get_type_hints(cls)
    found: list[Setting] = []
    for f in fields(cls):
        hint = hints[f.name]
        if isinstance(hint, type) and is_dataclass(hint):
            found += settings_of(hint, f"{prefix}{f.name}.")
            continue
        if "help" not in f.metadata:
            continue  # internal: not a user setting
        kind, _ = _value_type(hint)
        if f.metadata["positional"]:
            flag = f.name
        elif f.metadata["flag"]:
            flag = f.metadata["flag"]
        elif kind is bool and f.default is True:
            flag = "--no-" + f.name.replace("_", "-")
        else:
            flag = "--" + f.name.replace("_", "-")
        found.append(Setting(prefix + f.name, flag, f, kind))
    return found


def _help(s: Setting) -> str:
    text = s.meta["help"]
    default = s.field.default
    if s.kind is not bool and default not in (MISSING, None, ()) and "default" not in text:
        joiner = "x" if s.meta["metavar"] == "HxW" else ","  # sizes as written on the command line
        shown = joiner.join(map(str, default)) if isinstance(default, tuple) else default
        text += f" (default {shown})"
    return text.replace("%", "%%")


def add_config_flags(p: Flags, cls: type, skip: tuple[str, ...] = ()) -> list[Setting]:
    """Add a flag (or positional) for every setting of `cls` except the dotted paths in `skip`; returns them.
    Raises ValueError when two settings would take the same flag (a programming error, caught by the tests)."""
    added: list[Setting] = []
    seen: dict[str, str] = {}
    groups: dict[str, Flags] = {}
    wanted = [s for s in settings_of(cls) if s.path not in skip]
    required_groups = {s.meta["exclusive"] for s in wanted if s.meta["exclusive"] is not None and s.meta["required"]}
    for s in wanted:
        if s.flag in seen:
            raise ValueError(f"{cls.__name__}: {s.path} and {seen[s.flag]} both want {s.flag}")
        seen[s.flag] = s.path
        meta = s.meta
        group = meta["exclusive"]
        if group is not None and group not in groups:
            groups[group] = p.add_mutually_exclusive_group(required=group in required_groups)  # type: ignore[attr-defined]
        target = groups[group] if group is not None else p
        names = (s.flag, *meta["aliases"])
        kwargs: dict[str, Any] = {"help": _help(s)}
        if meta["positional"]:
            if meta["many"] or meta["optional"]:
                kwargs["nargs"] = ("*" if meta["many"] else "?") if meta["optional"] else "+"
            kwargs["type"] = s.kind if s.kind in (int, float, Path) else None
            kwargs["metavar"] = meta["metavar"]
            kwargs["choices"] = meta["choices"]
            p.add_argument(s.path, **{k: v for k, v in kwargs.items() if v is not None})
        elif s.kind is bool:
            action = "store_false" if s.field.default is True else "store_true"
            target.add_argument(*names, dest=s.path, action=action, **kwargs)
        else:
            default_given = s.field.default is not MISSING
            kwargs.update(
                dest=s.path,
                default=None,
                metavar=meta["metavar"] or (None if meta["choices"] else s.field.name.upper()),
                choices=meta["choices"],
                required=group is None and (meta["required"] or not default_given),
                action="append" if meta["many"] else None,
                nargs="?" if meta["const"] is not None else None,
                const=meta["const"],
            )
            if s.kind in (int, float, Path) and meta["parse"] is None:
                kwargs["type"] = s.kind
            target.add_argument(*names, **{k: v for k, v in kwargs.items() if v is not None or k == "default"})
        added.append(s)
    return added


_KEY_VALUE = re.compile(r"[A-Za-z_]\w*(\.\w+)*=.*", re.DOTALL)  # an override, never a path


def _overrides_out_of_const_flags(cls: type, args: argparse.Namespace) -> None:
    """A `const` flag given a KEY=VALUE: the flag takes its `const`, the positional `many` setting the value."""
    settings = settings_of(cls)
    rest = next((s for s in settings if s.meta["positional"] and s.meta["many"]), None)
    for s in settings:
        value = getattr(args, s.path, None)
        if rest is not None and s.meta["const"] is not None and isinstance(value, str) and _KEY_VALUE.fullmatch(value):
            setattr(args, s.path, s.meta["const"])
            setattr(args, rest.path, [value, *(getattr(args, rest.path, None) or [])])


def config_from_args(cls: type, args: argparse.Namespace, prefix: str = "", **given: Any) -> Any:
    """The config `cls` from parsed flags: each setting's value as given (its `parse` applied, a
    positional `many` as a tuple), else its declared default; `given` sets fields directly (dotted
    paths for nested ones: `**{"run.progress": True}`), e.g. the shared flags (`--out`, `--progress`)."""
    if not prefix:
        _overrides_out_of_const_flags(cls, args)
    hints = typing.get_type_hints(cls)
    values: dict[str, Any] = {}
    for f in fields(cls):
        path = prefix + f.name
        hint = hints[f.name]
        if path in given:
            values[f.name] = given[path]
        elif isinstance(hint, type) and is_dataclass(hint):
            values[f.name] = config_from_args(hint, args, path + ".", **given)
        elif "help" in f.metadata and getattr(args, path, None) is not None:
            value = getattr(args, path)
            parse, flag = f.metadata["parse"], f.metadata["flag"] or "--" + f.name.replace("_", "-")
            if f.metadata["many"]:
                value = tuple(value if parse is None else (parse(v, flag) for v in value))
            elif parse is not None:
                value = parse(value, flag)
            values[f.name] = value
    return cls(**values)
