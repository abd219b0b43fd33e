"""pyproject.toml lists every package of the tree, and every path it names exists."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESOURCES = "pipeline._resources."


@pytest.fixture(scope="module")
def setuptools_cfg() -> dict:
    with open(ROOT / "pyproject.toml", "rb") as f:
        return tomllib.load(f)["tool"]["setuptools"]


def _tree_packages() -> set[str]:
    found = set()
    for top in ("pipeline", "jobs"):
        for init in (ROOT / top).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT)
            if any(part.startswith((".", "__pycache__")) for part in rel.parts):
                continue
            found.add(".".join(rel.parts))
    return found


def test_tree_has_packages():
    found = _tree_packages()
    assert {"pipeline", "jobs", "pipeline.decode", "pipeline.io"} <= found


def test_every_package_directory_is_listed(setuptools_cfg):
    listed = set(setuptools_cfg["packages"])
    missing = sorted(_tree_packages() - listed)
    assert not missing, f"packages with an __init__.py missing from pyproject.toml: {missing}"


def test_packages_are_listed_once(setuptools_cfg):
    listed = setuptools_cfg["packages"]
    assert len(listed) == len(set(listed))


def test_every_listed_package_exists(setuptools_cfg):
    package_dir = setuptools_cfg.get("package-dir", {})
    for name in setuptools_cfg["packages"]:
        if name.startswith(RESOURCES):
            assert name in package_dir, f"{name} has no [tool.setuptools.package-dir] entry"
            continue
        path = ROOT.joinpath(*name.split("."))
        assert (path / "__init__.py").is_file(), f"listed package {name} has no {path}/__init__.py"


def test_resource_package_dirs(setuptools_cfg):
    package_dir = setuptools_cfg["package-dir"]
    resources = {n for n in setuptools_cfg["packages"] if n.startswith(RESOURCES)}
    assert resources == {RESOURCES + "schemas", RESOURCES + "sql", RESOURCES + "config"}
    for name, target in package_dir.items():
        assert name in setuptools_cfg["packages"], f"package-dir maps unlisted package {name}"
        assert target == name.removeprefix(RESOURCES)
        folder = ROOT / target
        assert folder.is_dir(), f"package-dir target {target} of {name} does not exist"
        assert any(p.is_file() for p in folder.iterdir()), f"{target} is empty"


def test_package_data_keys_are_listed_packages(setuptools_cfg):
    for name in setuptools_cfg.get("package-data", {}):
        assert name in setuptools_cfg["packages"], name


def test_extension_sources_exist(setuptools_cfg):
    exts = setuptools_cfg["ext-modules"]
    names = {e["name"] for e in exts}
    assert names == {"pipeline.decode._json_columns", "pipeline.io._mcap_records",
                     "pipeline.maritime._associate", "pipeline.filters._particle"}
    for ext in exts:
        assert ext["sources"], ext["name"]
        for src in [*ext["sources"], *ext.get("depends", [])]:
            assert (ROOT / src).is_file(), f"{ext['name']}: {src} does not exist"
        # the module lives in a listed package, next to its C source
        package, _, module = ext["name"].rpartition(".")
        assert package in setuptools_cfg["packages"]
        assert ext["sources"][0] == "/".join([*package.split("."), module]) + ".c"
