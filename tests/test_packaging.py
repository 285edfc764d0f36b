"""Packaging: every Python package in the tree ships in the wheel, and every install imports its own files."""

import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
SETUPTOOLS = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def test_every_package_folder_is_listed_in_pyproject() -> None:
    """A package folder under compd/, drivers/ or config/ missing from pyproject's list would vanish from a wheel."""
    roots = {"compd": ROOT / "compd"} | {
        package: ROOT / folder for package, folder in SETUPTOOLS["package-dir"].items()
    }
    found = {
        ".".join((package, *init.parent.relative_to(folder).parts))
        for package, folder in roots.items()
        for init in folder.rglob("__init__.py")
    }
    assert "compd.drivers.modbus" in found
    assert found - set(SETUPTOOLS["packages"]) == set()


def git(*argv: str) -> str:
    try:
        done = subprocess.run(["git", *argv], cwd=ROOT, capture_output=True, text=True, timeout=60)
    except FileNotFoundError:
        pytest.skip("git is not installed")
    if done.returncode != 0:
        pytest.skip(f"not a git checkout: {done.stderr.strip()}")
    return done.stdout


def test_the_repository_holds_no_symlink() -> None:
    """drivers/ reaches compd.drivers by package-dir alone: a link would resolve to whatever it points at."""
    links = [line for line in git("ls-files", "-s").splitlines() if line.startswith("120000 ")]
    assert links == []


#: Run by the fresh environment's Python, outside any checkout: where compd's files come from.
WHERE = """
import json
import compd, compd.drivers, compd.drivers.modbus.driver
from compd.drivers.registry import load_driver_type
from compd.files.yamlplace import resolve_path
print(json.dumps({
    "compd": compd.__file__,
    "drivers": compd.drivers.__file__,
    "modbus": load_driver_type("modbus").__module__,
    "bundled": str(resolve_path("bundled:simulated.yaml", ".")),
}))
"""


def side_clone(dest: Path) -> Path:
    """A second clone: this checkout's files as they are now (tracked and new), without the tests."""
    listed = git("ls-files", "-z", "--cached", "--others", "--exclude-standard").split("\0")
    for name in listed:
        source = ROOT / name
        wanted = name.split("/")[0] in ("compd", "drivers", "config", "share") or "/" not in name
        if wanted and source.is_file() and not source.is_symlink():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, dest / name)
    return dest


def site_directories() -> list[str]:
    """The site directories this Python imports from, in its order: a venv's, the system's, the user's."""
    return [
        entry for entry in sys.path
        if Path(entry).name in ("site-packages", "dist-packages") and Path(entry).is_dir()
    ]  # fmt: skip


def sees_this_environment(python: Path) -> Path:
    """Have the venv of ``python`` import, after its own packages, from this Python's site directories.

    ``venv --system-site-packages`` would show it the *base* interpreter's
    packages: from inside a venv (how most people run the suite) not this
    one's, where the dependencies are. A ``.pth`` file in the new venv's
    site-packages adds each of this Python's site directories with
    ``site.addsitedir``, so their own ``.pth`` files (an editable install's
    finder) are processed too. Named to sort after an install's own ``.pth``
    files and appended to ``sys.path``: what the new venv installs wins.
    """
    purelib = subprocess.run(
        [python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
        capture_output=True, text=True, check=True,
    ).stdout.strip()  # fmt: skip
    lines = [f"import site; site.addsitedir({entry!r})\n" for entry in site_directories()]
    pth = Path(purelib) / "zz-compd-tests-outer-environment.pth"
    pth.write_text("".join(lines))
    return pth


@pytest.mark.slow
@pytest.mark.parametrize("editable", [True, False], ids=["pip install -e", "pip install"])
def test_a_second_clone_installed_imports_its_own_drivers_and_configs(
    tmp_path: Path, editable: bool
) -> None:
    """Another clone installed in a fresh environment imports compd.drivers and bundled: from its own files.

    The environment sees this checkout's install too (:func:`sees_this_environment`;
    ``--no-deps``: no download): the new install must win for every file. About 15 s.
    """
    clone = side_clone(tmp_path / "clone")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", venv], check=True)
    python = venv / "bin" / "python"
    sees_this_environment(python)
    install = [python, "-m", "pip", "install", "-q", "--no-deps", "--disable-pip-version-check"]
    installed = subprocess.run(
        [*install, *(["-e"] if editable else []), clone],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert installed.returncode == 0, installed.stdout + installed.stderr
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    done = subprocess.run(
        [python, "-c", WHERE], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stdout + done.stderr
    where = {key: Path(value) for key, value in json.loads(done.stdout).items() if key != "modbus"}
    home = clone if editable else venv
    assert all(path.is_relative_to(home) for path in where.values()), where
    if editable:
        assert where["drivers"] == clone / "drivers" / "__init__.py"
        assert where["bundled"] == clone / "config" / "simulated.yaml"
    else:
        assert where["drivers"].parent == where["compd"].parent / "drivers"
    assert json.loads(done.stdout)["modbus"] == "compd.drivers.modbus.driver"
    if not editable:  # an editable install installs no data files: the clone has the page
        _man_finds_the_page(venv, clone)


def _man_finds_the_page(venv: Path, clone: Path) -> None:
    """``man compd`` finds the installed page from the venv's bin/ on PATH (no MANPATH) and formats it."""
    page = venv / "share" / "man" / "man1" / "compd.1"
    assert page.read_text() == (clone / "share" / "man" / "man1" / "compd.1").read_text()
    if shutil.which("man") is None:
        return  # the page is where man looks; man-db itself is not installed here
    env = {"PATH": f"{venv / 'bin'}:/usr/bin:/bin", "MANPAGER": "cat", "MANWIDTH": "100"}
    found = subprocess.run(["man", "-w", "compd"], env=env, capture_output=True, text=True)
    assert found.stdout.strip() == str(page), found.stderr
    shown = subprocess.run(["man", "-l", str(page)], env=env, capture_output=True, text=True)
    assert shown.returncode == 0 and "EXIT STATUS" in shown.stdout, shown.stderr
