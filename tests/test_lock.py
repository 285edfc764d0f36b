"""The lock pins what compd is tested and installed with: every dependency, inside pyproject's ranges."""

from __future__ import annotations

import re
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).parent.parent
LOCK = ROOT / ".ci" / "requirements.lock"


def pins() -> dict[str, Version]:
    found = re.findall(r"^([A-Za-z0-9_.\-]+)==(\S+)", LOCK.read_text(), re.M)
    return {canonicalize_name(name): Version(version) for name, version in found}


def declared() -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    texts = [*project["dependencies"], *(text for extra in extras.values() for text in extra)]
    requirements = [Requirement(text.split("#")[0].strip()) for text in texts]
    # `compd[toolkit]` in the test extra is compd itself (pip resolves it to the project).
    return [r for r in requirements if canonicalize_name(r.name) != project["name"]]


@pytest.mark.parametrize("requirement", declared(), ids=str)
def test_every_declared_dependency_is_pinned_inside_its_range(requirement: Requirement) -> None:
    """Each of pyproject's dependencies (core and every extra) has one pin that its range admits."""
    pinned = pins().get(canonicalize_name(requirement.name))
    assert pinned is not None, f"{requirement.name} is not in {LOCK}: run bash .ci/refresh-lock"
    assert requirement.specifier.contains(pinned, prereleases=True), (requirement, pinned)


def test_the_core_dependencies_installed_are_the_pinned_ones() -> None:
    """What runs the suite is what the lock pins: the README's commands install with ``-c`` the lock."""
    locked = pins()
    wrong = {}
    for requirement in declared():
        name = canonicalize_name(requirement.name)
        try:
            installed = Version(metadata.version(requirement.name))
        except metadata.PackageNotFoundError:
            continue  # an extra not installed here (dev tools on a test-only machine)
        if installed != locked[name]:
            wrong[requirement.name] = f"{installed} installed, {locked[name]} pinned"
    assert not wrong, f"reinstall with pip install -c {LOCK.relative_to(ROOT)} ...: {wrong}"
