"""The layering rules of the design notes, checked by walking every module's imports."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STDLIB = set(sys.stdlib_module_names)


def imported_modules(path: Path) -> set[str]:
    """Absolute names of every module imported by a Python file (relative imports resolved)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                names.add(".".join(base + ([node.module] if node.module else [])))
            else:
                names.add(node.module or "")
    return names


def python_files(folder: str) -> list[Path]:
    return sorted((ROOT / folder).rglob("*.py"))


def offenders(folder: str, forbidden) -> list[str]:
    return [f"{path.relative_to(ROOT)} imports {name}" for path in python_files(folder) for name in imported_modules(path) if forbidden(path, name)]


def top(name: str) -> str:
    return name.split(".")[0]


def test_library_never_imports_zenoh_or_services():
    assert offenders("locnerf", lambda _, n: top(n) in {"zenoh", "services"}) == []


def test_only_the_transport_imports_zenoh():
    assert offenders("services", lambda p, n: top(n) == "zenoh" and "transport" not in p.parts) == []


def test_geometry_imports_only_torch_numpy_and_itself():
    allowed = {"torch", "numpy", "__future__"}
    assert offenders("locnerf/geometry", lambda _, n: not (top(n) in allowed | STDLIB or n.startswith("locnerf.geometry"))) == []


def test_render_never_imports_field():
    assert offenders("locnerf/render", lambda _, n: n.startswith("locnerf.field")) == []


def test_filter_reaches_rendering_only_through_the_measurement_model():
    def forbidden(path: Path, name: str) -> bool:
        rendering = name.startswith("locnerf.render") and name != "locnerf.render.camera"
        return (rendering and path.name != "measurement.py") or name.startswith("locnerf.field")

    assert offenders("locnerf/filter", forbidden) == []


@pytest.mark.parametrize("folder", ["locnerf", "services"])
def test_no_print_in_library_code(folder):
    prints = []
    for path in python_files(folder):
        if "cli" in path.relative_to(ROOT).parts:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print":
                prints.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert prints == []
