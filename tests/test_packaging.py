"""The wheel's package list: every folder of the product that holds an ``__init__.py`` is installed, under a
name that starts with ``locnerf`` (the folders services/ and cli/ install as locnerf_services and locnerf_cli)."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def setuptools_table() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def installed_name(folder: Path, package_dir: dict[str, str]) -> str:
    """``services/filter_loop`` -> ``locnerf_services.filter_loop`` under the pyproject's folder mapping."""
    head, *rest = folder.parts
    package_of_folder = {directory: package for package, directory in package_dir.items()}
    return ".".join((package_of_folder.get(head, head), *rest))


def test_every_package_folder_is_listed_and_nothing_else():
    table = setuptools_table()
    folders = [init.parent.relative_to(ROOT) for top in ("locnerf", "services", "cli") for init in (ROOT / top).rglob("__init__.py")]
    expected = sorted(installed_name(folder, table.get("package-dir", {})) for folder in folders)
    assert sorted(table["packages"]) == expected


def test_installed_top_level_names_cannot_collide():
    assert {name.split(".")[0] for name in setuptools_table()["packages"]} == {"locnerf", "locnerf_services", "locnerf_cli"}


def test_the_console_script_points_into_the_installed_cli():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts == {"locnerf": "locnerf_cli.main:main"}
