"""The import graph of the source tree, read with ``ast`` (nothing is imported).

Imports point down the rooms: brdf <- skin_bssrdf <- stage <- relight, with no
cycles between the packages or between relight's subpackages; inside relight
the CLI sits on top (no one imports it, and its commands do not import each
other), and the fitter and the renderer sit side by side above io, envmap,
image and materials. Every import counts, also one inside a function: a lazy
import is still a dependency.
"""

from __future__ import annotations

import ast
import importlib.metadata
import re
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("brdf", "skin_bssrdf", "stage", "relight")

# (b) what each top-level package may import of ours.
ALLOWED = {
    "brdf": set(),
    "skin_bssrdf": {"brdf"},
    "stage": {"brdf", "skin_bssrdf"},
    "relight": {"brdf", "skin_bssrdf", "stage"},
}

# Third-party imports: the lower rooms stay light (docs/ARCHITECTURE.md's "may import" column; jaxtyping, for the
# annotations, is everywhere). relight may use any declared dependency.
THIRD_PARTY = {
    "brdf": {"jax", "equinox", "numpy", "jaxtyping", "h5py"},  # h5py: the NBRDF networks of measured materials
    "skin_bssrdf": {"jax", "equinox", "numpy", "jaxtyping", "scipy"},
    "stage": {"jax", "equinox", "numpy", "jaxtyping", "scipy", "trimesh"},
    "relight": None,
}

# (d) relight's layering (docs/ARCHITECTURE.md): a subpackage imports only subpackages of a lower layer, so
# image, materials and results (result sets, atomic writes) import none, io may use them, envmap, evaluation
# (held-out scoring), export (exporters) and simulation (simulated captures written whole) io, fitting and
# render everything below them but not each other, patterns (learned lighting) and view (the results viewer)
# everything below them but not each other, demo (relight demo as one call) everything below it, and cli all.
LAYER = {"image": 0, "materials": 0, "results": 0, "io": 1, "envmap": 2, "evaluation": 2, "export": 2,
         "simulation": 2, "fitting": 3, "render": 3, "patterns": 4, "view": 4, "demo": 5, "cli": 6}


@dataclass(frozen=True)
class Edge:
    source: str  # importing module, dotted
    target: str  # imported module, dotted (resolved to one of ours)
    where: str  # path:line

    def __str__(self):
        return f"{self.where}: {self.source} imports {self.target}"


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the four packages."""
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _package_of(module: str) -> str:
    """The package a module's relative imports start from."""
    return module if MODULES[module].name == "__init__.py" else module.rpartition(".")[0]


def _ours(name: str) -> str | None:
    """The longest prefix of ``name`` that is one of our modules (None if none is)."""
    parts = name.split(".")
    for n in range(len(parts), 0, -1):
        candidate = ".".join(parts[:n])
        if candidate in MODULES:
            return candidate
    return None


def _imports(module: str) -> list[Edge]:
    path = MODULES[module]
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    rel = path.relative_to(ROOT).as_posix()
    edges = []
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = _package_of(module).split(".")
                base = base[: len(base) - (node.level - 1)]
                stem = ".".join(base + ([node.module] if node.module else []))
            else:
                stem = node.module
            # `from pkg import name` imports pkg, and pkg.name too when that is a module
            targets = [stem] + [f"{stem}.{alias.name}" for alias in node.names]
        for name in targets:
            target = _ours(name)
            edge = Edge(module, target, f"{rel}:{node.lineno}")
            if target is not None and target != module and edge not in edges:
                edges.append(edge)
    return edges


EDGES = [edge for module in MODULES for edge in _imports(module)]


def _third_party() -> list[tuple[str, str, str]]:
    """(module, top-level import name, path:line) of every import that is neither ours nor the standard library."""
    out = []
    for module, path in MODULES.items():
        rel = path.relative_to(ROOT).as_posix()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top not in PACKAGES and top not in sys.stdlib_module_names:
                    out.append((module, top, f"{rel}:{node.lineno}"))
    return out


THIRD = _third_party()


def _top(module: str) -> str:
    return module.split(".")[0]


def _relight_unit(module: str) -> str:
    """relight's subpackage of a module ("relight" for the package root itself)."""
    parts = module.split(".")
    return ".".join(parts[:2]) if len(parts) > 1 else "relight"


def _cycles(nodes: set[str], edges: list[tuple[str, str, Edge]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan)."""
    graph = {n: sorted({b for a, b, _ in edges if a == n and b != n}) for n in nodes}
    index, low, on_stack, stack, out = {}, {}, set(), [], []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
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
            if len(comp) > 1:
                out.append(sorted(comp))

    for n in sorted(nodes):
        if n not in index:
            visit(n)
    return out


def _explain(components, edges) -> str:
    lines = []
    for comp in components:
        lines.append(f"cycle among {', '.join(comp)}:")
        lines += [f"  {e}" for a, b, e in edges if a in comp and b in comp and a != b]
    return "\n".join(lines)


def test_the_tree_is_found():
    assert {"brdf", "skin_bssrdf", "stage", "relight", "relight.cli", "relight.fitting"} <= set(MODULES)
    assert len(EDGES) > 50  # the parser sees the imports (a silent empty graph would pass everything)
    pairs = {(e.source, e.target) for e in EDGES}
    assert ("relight", "relight.fitting") in pairs  # `from . import fitting` in a package's __init__.py
    assert ("skin_bssrdf._convert", "brdf") in pairs  # `from brdf import safe_div, ...`


def test_no_cycles_between_packages():
    edges = [(_top(e.source), _top(e.target), e) for e in EDGES]
    components = _cycles(set(PACKAGES), edges)
    assert not components, _explain(components, edges)


def test_no_cycles_between_relight_subpackages():
    inside = [e for e in EDGES if _top(e.source) == "relight" and _top(e.target) == "relight"]
    edges = [(_relight_unit(e.source), _relight_unit(e.target), e) for e in inside]
    nodes = {_relight_unit(m) for m in MODULES if _top(m) == "relight"}
    components = _cycles(nodes, edges)
    assert not components, _explain(components, edges)


@pytest.mark.parametrize("package", PACKAGES)
def test_packages_import_only_down(package):
    bad = [e for e in EDGES if _top(e.source) == package and _top(e.target) not in ALLOWED[package] | {package}]
    allowed = ", ".join(sorted(ALLOWED[package])) or "nothing of ours"
    assert not bad, f"{package} may import {allowed}; found:\n" + "\n".join(map(str, bad))


@pytest.mark.parametrize("package", [p for p in PACKAGES if THIRD_PARTY[p] is not None])
def test_lower_packages_stay_light(package):
    bad = [
        f"{where}: {module} imports {top}"
        for module, top, where in THIRD
        if _top(module) == package and top not in THIRD_PARTY[package]
    ]
    allowed = ", ".join(sorted(THIRD_PARTY[package]))
    assert not bad, f"{package} may import (third party) {allowed}; found:\n" + "\n".join(bad)


def _normal(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def test_every_third_party_import_is_a_declared_dependency():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    declared = {_normal(re.match(r"[A-Za-z0-9_.-]+", d).group(0)) for d in project["dependencies"]}
    provides = importlib.metadata.packages_distributions()  # import name -> distributions (installed ones)
    bad = []
    for module, top, where in THIRD:
        dists = {_normal(d) for d in provides.get(top, [top])}
        if not dists & declared:
            bad.append(f"{where}: {module} imports {top} ({', '.join(sorted(dists))}: not in [project.dependencies])")
    assert not bad, "\n".join(sorted(set(bad)))


def test_only_the_cli_imports_the_cli():
    bad = [e for e in EDGES if _relight_unit(e.target) == "relight.cli" and _relight_unit(e.source) != "relight.cli"]
    assert not bad, "relight.cli sits on top; found:\n" + "\n".join(map(str, bad))


def _is_command(module: str) -> bool:
    """relight/cli/<command>.py: a public module of relight.cli (not its __init__, not _common or other _private)."""
    parts = module.split(".")
    return len(parts) == 3 and parts[:2] == ["relight", "cli"] and not parts[2].startswith("_")


def test_cli_commands_do_not_import_each_other():
    # A command may use relight.cli._common (and other private helpers); another command,
    # or the dispatcher relight/cli/__init__.py (which imports every command), it may not.
    bad = [e for e in EDGES if _is_command(e.source) and (_is_command(e.target) or e.target == "relight.cli")]
    assert not bad, "one CLI command imports another:\n" + "\n".join(map(str, bad))


def test_every_relight_subpackage_has_a_layer():
    subs = {_relight_unit(m).removeprefix("relight.") for m in MODULES if _top(m) == "relight" and m != "relight"}
    assert subs - {"data"} == set(LAYER), "a new relight subpackage needs its place in LAYER (docs/ARCHITECTURE.md)"


@pytest.mark.parametrize("sub", sorted(LAYER, key=LAYER.get))
def test_relight_layering(sub):
    unit = f"relight.{sub}"
    allowed = sorted(s for s in LAYER if LAYER[s] < LAYER[sub])
    bad = [
        e
        for e in EDGES
        if _relight_unit(e.source) == unit
        and _relight_unit(e.target).startswith("relight.")
        and _relight_unit(e.target) != unit
        and LAYER.get(_relight_unit(e.target).removeprefix("relight."), -1) >= LAYER[sub]
    ]
    # the root package imports every subpackage but cli (relight/__init__.py): importing it imports them all
    if sub != "cli":
        bad += [e for e in EDGES if _relight_unit(e.source) == unit and e.target == "relight"]
    may = f"only {', '.join(allowed)}" if allowed else "no other relight subpackage"
    assert not bad, f"{unit} may import {may}; found:\n" + "\n".join(map(str, bad))


def test_the_cycle_finder_finds_cycles():
    e = Edge("a", "b", "x.py:1")
    assert _cycles({"a", "b", "c"}, [("a", "b", e), ("b", "c", e), ("c", "a", e)]) == [["a", "b", "c"]]
    assert _cycles({"a", "b", "c"}, [("a", "b", e), ("b", "c", e), ("a", "c", e)]) == []


# (e) Rooms with one job and thin commands (issue 26; docs/ARCHITECTURE.md "Rules of shape").
# optimistix's largest module is 645 lines; ours stay under MAX_MODULE_LINES, and a command, which only parses,
# calls one library function and prints, under MAX_COMMAND_LINES.
MAX_MODULE_LINES = 600
MAX_COMMAND_LINES = 350
# The spellings of the render methods: strings belong to the CLI; relight.render dispatches on Modules.
RENDER_METHOD_NAMES = {"rig", "dense", "fast", "reference", "lights"}


def _lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def test_no_module_is_a_room_with_several_jobs():
    long = [f"{p.relative_to(ROOT)}: {_lines(p)} lines" for p in MODULES.values() if _lines(p) > MAX_MODULE_LINES]
    assert not long, f"modules over {MAX_MODULE_LINES} lines (split them by job):\n" + "\n".join(long)


def test_commands_are_thin():
    long = [f"{MODULES[m].relative_to(ROOT)}: {_lines(MODULES[m])} lines" for m in MODULES
            if _relight_unit(m) == "relight.cli" and _lines(MODULES[m]) > MAX_COMMAND_LINES]
    why = "move the logic into the library"
    assert not long, f"CLI modules over {MAX_COMMAND_LINES} lines ({why}):\n" + "\n".join(long)


def _private_imports(module: str, source: str | None = None) -> list[str]:
    """`path:line: name` for each private name (a `_x` module or a `_x` attribute) that ``module`` imports from
    a package other than its own subpackage (``source``: the module's text, default its file's)."""
    path = MODULES[module]
    rel = path.relative_to(ROOT).as_posix()
    unit = _relight_unit(module) if _top(module) == "relight" else _top(module)
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8") if source is None else source)):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = _package_of(module).split(".")
                base = base[: len(base) - (node.level - 1)]
                stem = ".".join(base + ([node.module] if node.module else []))
            else:
                stem = node.module or ""
            names = [f"{stem}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        for name in names:
            if _top(name) not in PACKAGES:
                continue
            home = _relight_unit(name) if _top(name) == "relight" else _top(name)
            if home == unit:
                continue
            if any(part.startswith("_") and part != "__init__" for part in name.split(".")):
                out.append(f"{rel}:{node.lineno}: {name}")
    return out


def test_commands_import_no_private_name_of_another_package():
    bad = [line for m in MODULES if _relight_unit(m) == "relight.cli" for line in _private_imports(m)]
    assert not bad, "the CLI uses only public library names; found:\n" + "\n".join(bad)


def test_the_private_import_finder_finds_them():
    source = ("from ..io._resultset import x\nfrom ..io import y\nimport stage._rig\nfrom . import _flags\n"
              "from ..render import _private_helper\nfrom stage import Rig\n")
    found = [line.rsplit(": ", 1)[1] for line in _private_imports("relight.cli", source)]
    assert found == ["relight.io._resultset.x", "stage._rig", "relight.render._private_helper"]


# (f) The scripts are users of the library (issue 26): they import its public names and scripts/_common.py (a
# script runs as `python scripts/x.py`, and Python puts the script's folder first on sys.path), never a private
# module or name of brdf, skin_bssrdf, stage or relight, and they do not edit sys.path.
SCRIPTS = sorted((ROOT / "scripts").glob("*.py"))
SYS_PATH_EDITS = {"insert", "append", "extend", "remove", "pop", "clear", "reverse", "sort"}  # list's mutators


def _private_part(part: str) -> bool:
    """A private name: a leading underscore, but not a dunder (``__init__``, ``__version__``)."""
    return part.startswith("_") and not (part.startswith("__") and part.endswith("__"))


def _script_breaches(path: Path, source: str | None = None) -> list[str]:
    """`path:line: what` for each private name of our packages that a script imports and each edit of
    ``sys.path`` (``source``: the script's text, default its file's)."""
    rel = path.relative_to(ROOT).as_posix()
    tree = ast.parse(path.read_text(encoding="utf-8") if source is None else source)
    # The names `sys` is bound to (`import sys`, `import sys as s`): sys.path edits through any of them count.
    sys_names = {a.asname or a.name for node in ast.walk(tree) if isinstance(node, ast.Import)
                 for a in node.names if a.name == "sys"}

    def is_sys_path(node) -> bool:
        return (isinstance(node, ast.Attribute) and node.attr == "path" and isinstance(node.value, ast.Name)
                and node.value.id in sys_names)

    out = []
    for node in ast.walk(tree):
        names, edit = [], False
        if isinstance(node, ast.ImportFrom):
            stem = "." * node.level + (node.module or "")
            names = [f"{stem}.{a.name}" for a in node.names]
            edit = stem == "sys" and any(a.name == "path" for a in node.names)  # `from sys import path`
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            edit = is_sys_path(node.func.value) and node.func.attr in SYS_PATH_EDITS
        elif isinstance(node, (ast.Assign, ast.AugAssign, ast.AnnAssign, ast.Delete)):
            targets = node.targets if isinstance(node, (ast.Assign, ast.Delete)) else [node.target]
            edit = any(is_sys_path(t.value if isinstance(t, ast.Subscript) else t) for t in targets)
        for name in names:
            if _top(name) in PACKAGES and any(_private_part(part) for part in name.split(".")):
                out.append(f"{rel}:{node.lineno}: imports {name}")
        if edit:
            out.append(f"{rel}:{node.lineno}: edits sys.path")
    return out


def test_the_scripts_are_found():
    assert len(SCRIPTS) > 10 and ROOT / "scripts" / "_common.py" in SCRIPTS


def test_scripts_use_only_the_public_api_and_leave_sys_path_alone():
    bad = [line for path in SCRIPTS for line in _script_breaches(path)]
    why = "scripts import public library names and _common only, and do not edit sys.path"
    assert not bad, f"{why}; found:\n" + "\n".join(bad)


def test_the_script_checker_finds_breaches():
    source = ("import sys\nimport sys as system\nimport relight.fitting._model\n"
              "from relight.fitting import _solvers\nfrom relight.fitting._model import Layout\n"
              "from brdf import _nbrdf as nb\nfrom stage import __version__\nfrom relight.fitting import fit, Layout\n"
              "from _common import parser, _private_helper\nimport numpy._core\n"
              "sys.path.insert(0, 'x')\nsystem.path.append('y')\nsys.path[:0] = ['z']\nsys.path += ['w']\n"
              "sys.path = []\nfrom sys import path\nprint(sys.path)\nsys.argv.append('a')\n")
    found = [line.split(":", 2)[2].strip() for line in _script_breaches(ROOT / "scripts" / "x.py", source)]
    assert sorted(found) == sorted([
        "imports relight.fitting._model", "imports relight.fitting._solvers", "imports relight.fitting._model.Layout",
        "imports brdf._nbrdf", *["edits sys.path"] * 6,
    ])


def _string_dispatch(path: Path) -> list[str]:
    rel = path.relative_to(ROOT).as_posix()
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Compare):
            sides = [node.left, *node.comparators]
            consts = {s.value for s in sides if isinstance(s, ast.Constant) and isinstance(s.value, str)}
            for s in sides:
                if isinstance(s, (ast.Tuple, ast.List, ast.Set)):
                    consts |= {e.value for e in s.elts if isinstance(e, ast.Constant) and isinstance(e.value, str)}
            if consts & RENDER_METHOD_NAMES:
                out.append(f"{rel}:{node.lineno}: compares with {sorted(consts & RENDER_METHOD_NAMES)}")
        elif isinstance(node, ast.Match):
            out += [f"{rel}:{c.pattern.lineno}: match on a method name" for c in node.cases
                    if isinstance(c.pattern, ast.MatchValue) and getattr(c.pattern.value, "value", None)
                    in RENDER_METHOD_NAMES]
    return out


def test_no_string_dispatch_in_render():
    bad = [line for m, p in MODULES.items() if _relight_unit(m) == "relight.render" for line in _string_dispatch(p)]
    assert not bad, "relight.render dispatches on method Modules, not on their names:\n" + "\n".join(bad)


def test_the_dispatch_finder_finds_dispatch(tmp_path):
    p = tmp_path / "m.py"
    p.write_text("if method == 'dense':\n    pass\nif m in ('rig', 'x'):\n    pass\nok = name == 'other'\n")
    found = [line.split(": ", 1)[0].rsplit(":", 1)[1] for line in _string_dispatch_at(p)]
    assert found == ["1", "3"]


def _string_dispatch_at(path: Path) -> list[str]:
    """:func:`_string_dispatch` for a file outside the tree (the finder's own test)."""
    global ROOT
    saved, ROOT = ROOT, path.parent
    try:
        return _string_dispatch(path)
    finally:
        ROOT = saved
