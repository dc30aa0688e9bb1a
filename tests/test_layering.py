"""The layering rules of the design notes, checked by walking every module's imports.

Layers, bottom to top: ``locnerf`` (the library) <- ``services`` <- ``cli`` (the entry point); the
folders ``services`` and ``cli`` install as the packages ``locnerf_services`` and ``locnerf_cli``.
A module's imports are its ``import`` statements (anywhere in the file, functions included) and its
dynamic imports whose module name is a constant string (``importlib.import_module("x")``,
``__import__("x")``, ``importlib.util.find_spec("x")``, ...): those obey the same rules. A dynamic
import whose name is computed cannot be checked, so it is refused wherever it appears.
"""

from __future__ import annotations

import ast
import importlib.util
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STDLIB = set(sys.stdlib_module_names)
LAYERS = ("locnerf", "services", "cli")
PACKAGE_OF_FOLDER = {"locnerf": "locnerf", "services": "locnerf_services", "cli": "locnerf_cli"}

COMMAND_RUNNERS = {"services/warm_start.py"}
"""Files that run a command line's ``python -m MODULE`` as a process of its own (forked from a warm server where
subprocess.Popen would exec it): their one ``runpy.run_module`` of a computed name imports nothing into the process
that calls them, so it is not refused (its one such call is checked below)."""

# Calls that import the module named by their first argument.
DYNAMIC_IMPORTERS = {
    "__import__",
    "importlib.__import__",
    "importlib.import_module",
    "importlib.util.find_spec",
    "importlib.util.spec_from_file_location",
    "runpy.run_module",
}


@dataclass
class FileImports:
    """What one Python file imports: module names, and the lines of dynamic imports with a computed name."""

    modules: set[str] = field(default_factory=set)
    computed: list[int] = field(default_factory=list)


def dotted_name(node: ast.expr) -> str | None:
    """``a.b.c`` for a chain of attributes on a name; None for anything else."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        base = dotted_name(node.value)
        return None if base is None else f"{base}.{node.attr}"
    return None


def constant_string(node: ast.expr) -> str | None:
    """The value of a string literal; None for any other expression."""
    return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else None


def importer_aliases(tree: ast.AST) -> dict[str, str]:
    """Local names bound to importlib, runpy or their functions (``from importlib import import_module``)."""
    aliases: dict[str, str] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            aliases.update({alias.asname: alias.name for alias in node.names if alias.asname and alias.name.split(".")[0] in {"importlib", "runpy"}})
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in {"importlib", "runpy"}:
            aliases.update({alias.asname or alias.name: f"{node.module}.{alias.name}" for alias in node.names})
    return aliases


def dynamic_imports(tree: ast.AST) -> Iterator[tuple[ast.Call, str | None]]:
    """Every call of a dynamic importer, with the module it names (None when the name is computed)."""
    aliases = importer_aliases(tree)
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call) or (name := dotted_name(node.func)) is None:
            continue
        head, dot, rest = name.partition(".")
        if f"{aliases.get(head, head)}{dot}{rest}" not in DYNAMIC_IMPORTERS:
            continue
        module, package = (constant_string(node.args[i]) if len(node.args) > i else None for i in (0, 1))
        if module is None or (module.startswith(".") and package is None):
            yield node, None
        else:
            yield node, importlib.util.resolve_name(module, package)


def file_imports(path: Path, root: Path) -> FileImports:
    """Absolute names of every module a Python file imports, statically (relative imports resolved) or
    dynamically with a constant name, and the lines where a dynamic import's name is computed."""
    tree = ast.parse(path.read_text(), filename=str(path))
    folders = path.relative_to(root).with_suffix("").parts[:-1]
    package = ".".join((PACKAGE_OF_FOLDER.get(folders[0], folders[0]), *folders[1:])) if folders else ""
    found = FileImports()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.modules.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                found.modules.add(".".join(base + ([node.module] if node.module else [])))
            else:
                found.modules.add(node.module or "")
    for call, module in dynamic_imports(tree):
        if module is None:
            found.computed.append(call.lineno)
        else:
            found.modules.add(module)
    return found


def python_files(root: Path, folder: str) -> list[Path]:
    return sorted((root / folder).rglob("*.py"))


def offenders(folder: str, forbidden: Callable[[Path, str], bool], root: Path = ROOT) -> list[str]:
    """``<file> imports <module>`` for every import under ``folder`` that ``forbidden(path, module)`` refuses."""
    return [
        f"{path.relative_to(root)} imports {name}"
        for path in python_files(root, folder)
        for name in sorted(file_imports(path, root).modules)
        if forbidden(path, name)
    ]


def computed_dynamic_imports(folder: str, root: Path = ROOT) -> list[str]:
    """``<file>:<line>`` of every dynamic import under ``folder`` whose module name is not a constant, outside COMMAND_RUNNERS."""
    return [
        f"{path.relative_to(root)}:{line}"
        for path in python_files(root, folder)
        if path.relative_to(root).as_posix() not in COMMAND_RUNNERS
        for line in file_imports(path, root).computed
    ]


def top(name: str) -> str:
    return name.split(".")[0]


def library_breach(_: Path, name: str) -> bool:
    return top(name) in {"zenoh", "locnerf_services", "locnerf_cli"}


def services_breach(_: Path, name: str) -> bool:
    return top(name) == "locnerf_cli"


def test_library_never_imports_zenoh_services_or_the_cli():
    assert offenders("locnerf", library_breach) == []


def test_services_never_import_the_cli():
    assert offenders("services", services_breach) == []


@pytest.mark.parametrize("folder", LAYERS)
def test_every_dynamic_import_names_its_module(folder):
    assert computed_dynamic_imports(folder) == []


def test_a_command_runner_computes_one_module_name_and_imports_no_layer_above_its_own():
    for name in COMMAND_RUNNERS:
        imports = file_imports(ROOT / name, ROOT)
        assert len(imports.computed) == 1, f"{name}: expected one runpy.run_module of a command line's module"
        assert not any(services_breach(ROOT / name, module) for module in imports.modules)


def test_the_checker_sees_dynamic_imports(tmp_path):
    """A planted tree: hidden imports of the CLI from services and of services from the library are
    reported like plain ones, and a computed name is reported by its line."""
    (tmp_path / "services").mkdir()
    (tmp_path / "services" / "sneaky.py").write_text(
        "import importlib\n"
        "from importlib import import_module as load\n"
        "import importlib.util\n"
        "importlib.import_module('locnerf_cli.main')\n"
        "load('locnerf_cli.up')\n"
        "__import__('locnerf_cli')\n"
        "importlib.util.find_spec('locnerf_cli.run')\n"
        "importlib.import_module('.poses', 'locnerf_services')\n"
        "name = 'locnerf_cli.' + 'echo'\n"
        "importlib.import_module(name)\n"
    )
    (tmp_path / "locnerf").mkdir()
    (tmp_path / "locnerf" / "hidden.py").write_text("def transport():\n    return __import__('locnerf_services.transport')\n")

    assert offenders("services", services_breach, root=tmp_path) == [
        "services/sneaky.py imports locnerf_cli",
        "services/sneaky.py imports locnerf_cli.main",
        "services/sneaky.py imports locnerf_cli.run",
        "services/sneaky.py imports locnerf_cli.up",
    ]
    assert "locnerf_services.poses" in file_imports(tmp_path / "services" / "sneaky.py", tmp_path).modules
    assert computed_dynamic_imports("services", root=tmp_path) == ["services/sneaky.py:10"]
    assert offenders("locnerf", library_breach, root=tmp_path) == ["locnerf/hidden.py imports locnerf_services.transport"]


def test_only_the_transport_imports_zenoh():
    assert offenders("services", lambda p, n: top(n) == "zenoh" and "transport" not in p.parts) == []


def test_geometry_imports_only_torch_numpy_and_itself():
    allowed = {"torch", "numpy", "__future__"}
    assert offenders("locnerf/geometry", lambda _, n: not (top(n) in allowed | STDLIB or n.startswith("locnerf.geometry"))) == []


def test_render_never_imports_field():
    assert offenders("locnerf/render", lambda _, n: n.startswith("locnerf.field")) == []


def test_filter_reaches_rendering_only_through_the_measurement_models():
    """Rays and renders appear in the measurement models only: ``measurement.py`` (rendering from every
    particle), ``warp.py`` (re-projecting one reference render) and ``depth_measurement.py`` (the depth
    term, both ways); the filter never imports a map backend."""

    def forbidden(path: Path, name: str) -> bool:
        rendering = name.startswith("locnerf.render") and name != "locnerf.render.camera"
        return (rendering and path.name not in ("measurement.py", "warp.py", "depth_measurement.py")) or name.startswith("locnerf.field")

    assert offenders("locnerf/filter", forbidden) == []


@pytest.mark.parametrize("folder", ["locnerf", "services"])
def test_no_print_in_library_code(folder):
    prints = []
    for path in python_files(ROOT, folder):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print":
                prints.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert prints == []
