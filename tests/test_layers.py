"""The package's layers (docs/layout.md), checked on the installed modules' source with ``ast``.

A module imports only from its own layer or lower ones, no two modules import each other in a
circle, and no function imports one of the package's modules: every dependency shows at the top of
the file. A function may import only an optional heavy or platform-specific module (``FUNCTION_LEVEL``).
Imports under ``if TYPE_CHECKING:`` count like any other: an annotation is a dependency too."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import maglev_cosim

PACKAGE = "maglev_cosim"

#: The layers, lowest first: a module's layer is its top-level folder (or file) inside the package.
LAYERS = (
    {"_resources", "_html"},            # where the installed files are; Markdown -> HTML page
    {"plant"},                          # the C plant's bindings, parameters, formulas, the reference
    {"rigs"},                           # rig files and their loader
    {"loop"},                           # controllers, the closed loop, the FMU runner
    {"records"},                        # records of every format, the emulators, synth
    {"diagnosis"},                      # the one diagnosis engine, each path's stages and reports
    {"report"},                         # the benchmark
    {"cli", "__main__", "__init__"},    # the command line, the public API
)

#: Third-party (or platform-specific standard) modules a function may import: optional heavy
#: dependencies that ``import maglev_cosim`` should not load (python-control loads matplotlib.pyplot:
#: half a second of every command's start, which ``diagnose`` does not use; scipy.signal loads
#: scipy.stats: 0.7 s), and ``resource`` (not on Windows). A dotted name allows that module and its
#: own names and submodules only.
FUNCTION_LEVEL = {"matplotlib", "control", "markdown", "lxml", "fmu_manipulation_toolbox", "resource",
                  "scipy.signal"}


_PARSED: dict[Path, ast.Module] = {}


def modules(root: Path, patch: dict[str, str] | None = None) -> dict[str, ast.Module]:
    """Dotted name (``maglev_cosim.plant.fast``; a package is its ``__init__``) -> parsed source;
    ``patch``: lines to append to some files (path relative to ``root``), to show the check fails."""
    out = {}
    for f in sorted(root.rglob("*.py")):
        rel = f.relative_to(root)
        parts = [PACKAGE, *rel.with_suffix("").parts]
        if parts[-1] == "__init__":
            parts.pop()
        if patch and rel.as_posix() in patch:
            tree = ast.parse(f.read_text() + "\n" + patch[rel.as_posix()], str(f))
        else:
            if f not in _PARSED:
                _PARSED[f] = ast.parse(f.read_text(), str(f))
            tree = _PARSED[f]
        out[".".join(parts)] = tree
    return out


def layer(name: str) -> int:
    parts = name.split(".")
    top = parts[1] if len(parts) > 1 else "__init__"
    for i, members in enumerate(LAYERS):
        if top in members:
            return i
    raise AssertionError(f"{name}: its folder {top!r} is in no layer of LAYERS (add it, and to docs/layout.md)")


def _is_package(name: str, root: Path) -> bool:
    return (root.joinpath(*name.split(".")[1:]) / "__init__.py").is_file()


def imports(name: str, tree: ast.Module, mods: dict[str, ast.Module], root: Path):
    """Each import of the module: (line, target: the package module it loads or None, the dotted name
    of a third-party or standard module or of a name imported from it, in a function?)."""
    package = name if _is_package(name, root) else name.rsplit(".", 1)[0]

    def visit(node, in_function):
        for child in ast.iter_child_nodes(node):
            nested = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda,
                                                       ast.ClassDef))
            if isinstance(child, ast.Import):
                for alias in child.names:
                    if alias.name.split(".")[0] == PACKAGE:
                        yield child.lineno, alias.name, None, in_function
                    else:
                        yield child.lineno, None, alias.name, in_function
            elif isinstance(child, ast.ImportFrom):
                if child.level == 0 and (child.module or "").split(".")[0] != PACKAGE:
                    for alias in child.names:
                        yield child.lineno, None, f"{child.module}.{alias.name}", in_function
                    continue
                if child.level:
                    base = package.split(".")
                    base = base[:len(base) - (child.level - 1)]
                    target = ".".join(base + ([child.module] if child.module else []))
                else:
                    target = child.module
                for alias in child.names:
                    sub = f"{target}.{alias.name}"
                    yield child.lineno, (sub if sub in mods else target), None, in_function
            else:
                yield from visit(child, nested)

    yield from visit(tree, False)


def check(root: Path, patch: dict[str, str] | None = None) -> list[str]:
    """Every breach of the rules, one line each (empty: the package keeps its layers)."""
    mods = modules(root, patch)
    problems, edges = [], {n: set() for n in mods}
    for name, tree in mods.items():
        for line, target, external, in_function in imports(name, tree, mods, root):
            where = f"{name} (line {line})"
            if target is not None and target not in mods:
                problems.append(f"{where}: imports {target}, which is no module of the package")
            elif target is not None:
                if in_function:
                    problems.append(f"{where}: function-level import of {target}: import it at the top")
                if layer(target) > layer(name):
                    problems.append(f"{where}: imports {target}, a higher layer")
                if target != name:
                    edges[name].add(target)
            elif in_function and not any(external == f or external.startswith(f + ".") for f in FUNCTION_LEVEL):
                problems.append(f"{where}: function-level import of {external}: import it at the top "
                                "(or, if it is an optional heavy dependency, add it to FUNCTION_LEVEL)")
    problems += [f"import cycle: {' -> '.join(c)}" for c in cycles(edges)]
    return list(dict.fromkeys(problems))


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """One cycle per strongly connected component of more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(_loop(min(comp), set(comp), edges))

    for v in sorted(edges):
        if v not in index:
            strong(v)
    return out


def _loop(start: str, comp: set[str], edges: dict[str, set[str]]) -> list[str]:
    """A shortest way round from ``start`` back to it inside a strongly connected component."""
    paths, seen = [[start]], set()
    while paths:
        path = paths.pop(0)
        for w in sorted(edges[path[-1]] & comp):
            if w == start:
                return path + [start]
            if w not in seen:
                seen.add(w)
                paths.append(path + [w])
    raise AssertionError(f"no way round from {start}")


ROOT = Path(maglev_cosim.__file__).resolve().parent


def test_the_installed_package_keeps_its_layers():
    problems = check(ROOT)
    assert not problems, "\n".join(problems)


def test_every_module_has_a_layer_and_each_layer_a_module():
    names = modules(ROOT)
    used = {layer(n) for n in names}
    assert used == set(range(len(LAYERS)))


@pytest.mark.parametrize("where, source, expected", [
    ("plant/params.py", "from ..loop import pid\n", "a higher layer"),
    ("plant/params.py", "def f():\n    from . import fast\n", "function-level import of maglev_cosim.plant.fast"),
    ("plant/params.py", "def f():\n    import json\n", "function-level import of json"),
    ("plant/fast.py", "from . import params\n", "import cycle"),
    ("plant/fast.py", "if TYPE_CHECKING:\n    from .params import PlantParams\n", "import cycle"),
    ("records/synth.py", "def f():\n    import scipy.io\n", "function-level import of scipy"),
    ("loop/pid.py", "if True:\n    from ..records import record\n", "a higher layer"),
])
def test_the_check_finds_each_kind_of_breach(where, source, expected):
    problems = check(ROOT, {where: source})
    assert any(expected in p for p in problems), problems


def test_the_command_line_starts_without_the_heavy_optional_modules():
    # scipy.signal (with the scipy.stats it loads), python-control and matplotlib: 1.2 s of every
    # command's start that `diagnose` need not pay (FUNCTION_LEVEL)
    import subprocess
    import sys

    code = ("import sys, maglev_cosim.cli, maglev_cosim.diagnosis.real_rig, maglev_cosim.diagnosis.engine; "
            "print(sorted(m for m in ('scipy.signal', 'scipy.stats', 'control', 'matplotlib') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
