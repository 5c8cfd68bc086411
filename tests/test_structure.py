"""The code's shape, read from the source (AST): no module imports another module's private names,
no import circle among the project's modules, seeu_data never imports seeu_model or pipelines,
and the stage libraries of pipelines/ never import the CLI.

Imports inside functions count as well: a circle closed by a deferred import is still a circle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("seeu_data", "seeu_model", "pipelines")
CHECKED_FOR_PRIVATE = PACKAGES + ("tests", "benchmarks")


def module_files(top: tuple[str, ...], root: Path = ROOT) -> dict[str, tuple[Path, bool]]:
    """Dotted module name -> (file, is_package) for every .py file under the `top` directories."""
    mods: dict[str, tuple[Path, bool]] = {}
    for pkg in top:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if "fixtures" in parts:
                continue
            is_pkg = parts[-1] == "__init__"
            mods[".".join(parts[:-1] if is_pkg else parts)] = (path, is_pkg)
    return mods


def _target(module: str, is_pkg: bool, node: ast.ImportFrom) -> str | None:
    """The absolute module a `from X import ...` reads from (relative imports resolved)."""
    if not node.level:
        return node.module
    base = module.split(".") if is_pkg else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def scan(mods: dict[str, tuple[Path, bool]]) -> tuple[dict[str, set[str]], list[str]]:
    """(imports: module -> project modules it imports, private-name imports as 'a imports b._x' lines)."""
    graph: dict[str, set[str]] = {m: set() for m in mods}
    private: list[str] = []
    for mod, (path, is_pkg) in mods.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                graph[mod].update(a.name for a in node.names if a.name in mods)
            elif isinstance(node, ast.ImportFrom):
                target = _target(mod, is_pkg, node)
                if target is None:
                    continue
                for alias in node.names:
                    if f"{target}.{alias.name}" in mods:  # `from pkg import submodule`
                        graph[mod].add(f"{target}.{alias.name}")
                        continue
                    if target in mods:
                        graph[mod].add(target)
                    if _is_private(alias.name) and target != mod:
                        private.append(f"{mod} imports {target}.{alias.name}")
    return graph, private


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (or a module importing itself)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan; the module graph is shallow enough for recursion
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1 or v in graph[v]:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_private_names_imported_across_modules():
    _, private = scan(module_files(CHECKED_FOR_PRIVATE))
    assert not private, "import of another module's private name:\n" + "\n".join(private)


def test_no_import_circles():
    graph, _ = scan(module_files(PACKAGES))
    found = cycles(graph)
    assert not found, "import circles:\n" + "\n".join(" <-> ".join(c) for c in found)


@pytest.mark.parametrize(
    "package, forbidden",
    [
        ("seeu_data", ("seeu_model", "pipelines")),
        ("seeu_model", ("pipelines",)),
    ],
)
def test_layering(package, forbidden):
    graph, _ = scan(module_files(PACKAGES))
    bad = sorted(
        f"{m} imports {t}"
        for m, targets in graph.items()
        if m.split(".")[0] == package
        for t in targets
        if t.split(".")[0] in forbidden
    )
    assert not bad, "\n".join(bad)


# seeu_data's sub-packages, by the data they hold. store/ (files, schemas, manifests, posed frames) is
# the bottom: it reads only the shared basics. The stages beside it (ingest, build, importers,
# exporters, loader) read store/ and the basics, never one another.
DATA_BASICS = {"seeu_data", "seeu_data.errors", "seeu_data.limits", "seeu_data.cameras", "seeu_data.overlap"}
DATA_STAGES = ("ingest", "build", "importers", "exporters", "loader")


def _data_part(module: str) -> str | None:
    """'seeu_data.ingest.sfm' -> 'ingest'; a top-level seeu_data module -> None."""
    parts = module.split(".")
    return parts[1] if parts[0] == "seeu_data" and len(parts) > 2 else None


def _forbidden_imports(importer, forbidden) -> list[str]:
    """'a imports b' for every import of the project's modules where `importer(a)` and `forbidden(a, b)`."""
    graph, _ = scan(module_files(PACKAGES))
    return sorted(f"{m} imports {t}" for m, targets in graph.items() if importer(m) for t in targets if forbidden(m, t))


def test_store_reads_only_the_basics():
    bad = _forbidden_imports(
        lambda m: _data_part(m) == "store", lambda m, t: t not in DATA_BASICS and _data_part(t) != "store"
    )
    assert not bad, "\n".join(bad)


def test_data_stages_do_not_import_one_another():
    bad = _forbidden_imports(
        lambda m: _data_part(m) in DATA_STAGES,
        lambda m, t: _data_part(t) in DATA_STAGES and _data_part(t) != _data_part(m),
    )
    assert not bad, "\n".join(bad)


def test_stage_libraries_do_not_import_the_cli():
    """pipelines/<stage>.py is the library; pipelines/cli/ parses flags and calls it, never the reverse."""
    graph, _ = scan(module_files(PACKAGES))
    bad = sorted(
        f"{m} imports {t}"
        for m, targets in graph.items()
        if m.startswith("pipelines.") and not m.startswith("pipelines.cli")
        for t in targets
        if t == "pipelines.cli" or t.startswith("pipelines.cli.")
    )
    assert not bad, "\n".join(bad)


# Optional extras (pyproject.toml): the one module that may import each, so the rest works without it.
OPTIONAL_IMPORTS = {"lightning": "seeu_data.lightning", "pytorch_lightning": None}


def test_optional_extras_are_imported_by_their_module_only():
    """`lightning` is imported by seeu_data/lightning.py alone, and that module by nobody in the packages."""
    mods = module_files(PACKAGES)
    bad = []
    for mod, (path, _) in mods.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom) and not node.level
                else []
            )
            for name in names:
                top = name.split(".")[0]
                if top in OPTIONAL_IMPORTS and OPTIONAL_IMPORTS[top] != mod:
                    bad.append(f"{mod} imports {name}")
    graph, _ = scan(mods)
    bad += [f"{m} imports {t}" for m, ts in graph.items() for t in ts if t in OPTIONAL_IMPORTS.values()]
    assert not bad, "\n".join(sorted(bad))


def test_architecture_page_places_every_module():
    """docs/ARCHITECTURE.md is the map of the stages: every module of seeu_data and of its ingest/,
    build/ and store/ sub-packages, and every stage library of pipelines, is named there (by file name), so a
    new module cannot be left off it."""
    page = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    modules = [
        p
        for d in ("seeu_data", "seeu_data/ingest", "seeu_data/build", "seeu_data/store", "pipelines")
        for p in sorted((ROOT / d).glob("*.py"))
    ]
    named = [str(p.relative_to(ROOT)) for p in modules if p.name != "__init__.py"]
    missing = [n for n in named if Path(n).name not in page]
    assert not missing, f"not in docs/ARCHITECTURE.md: {missing}"


def _write(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_the_checks_find_what_they_look_for(tmp_path):
    """The scanner itself on a small made-up tree: a circle closed by a deferred import, a private name
    read across modules (relative and absolute), and what is allowed (dunders, own names, submodules)."""
    _write(
        tmp_path,
        {
            "pkg/__init__.py": '__version__ = "1"\n',
            "pkg/a.py": "from . import b\n",
            "pkg/b.py": "def f():\n    from pkg.a import g\n",
            "pkg/c.py": "from .d import _helper\nfrom pkg import __version__\n",
            "pkg/d.py": "from pkg.sub import _x\nfrom pkg import sub\n_helper = 1\n",
            "pkg/sub/__init__.py": "from ._impl import _y\n_x = 1\n",
            "pkg/sub/_impl.py": "_y = 2\n",
        },
    )
    graph, private = scan(module_files(("pkg",), tmp_path))
    assert cycles(graph) == [["pkg.a", "pkg.b"]]
    assert sorted(private) == [
        "pkg.c imports pkg.d._helper",
        "pkg.d imports pkg.sub._x",
        "pkg.sub imports pkg.sub._impl._y",
    ]
    assert graph["pkg.d"] == {"pkg.sub"} and graph["pkg.sub"] == {"pkg.sub._impl"}
