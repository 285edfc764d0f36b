"""The package laid out as a wheel installs it, for the tools that walk folders instead of importing.

``drivers/`` is installed as ``compd.drivers`` and ``config/`` as
``compd.bundled`` by pyproject.toml's ``package-dir`` alone; an editable
install maps them in its import finder, so Python imports the checkout's own
files. import-linter (through grimp) and mypy do not import: they look for
``compd/drivers/`` beside ``compd/`` and would not find it. They run on a copy
of the checkout's modules laid out at their import paths, with
``pyproject.toml`` beside them, so they read the same contracts and settings::

    python -m tests.installed lint-imports --no-cache
    python -m tests.installed lint-imports --no-cache drivers/importlinter.ini
    python -m tests.installed mypy

Copies, not links: nothing in the repository to break in a clone or on a
file system without links, and every run sees this checkout's files.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: import-linter's config of the driver interface's contract (the layers are pyproject.toml's).
DRIVER_CONTRACT = "drivers/importlinter.ini"


def package_folder(package: str, package_dir: dict[str, str]) -> Path:
    """The checkout's folder of ``package``, as setuptools maps it (the longest ``package-dir`` prefix)."""
    parts = package.split(".")
    for cut in range(len(parts), 0, -1):
        mapped = package_dir.get(".".join(parts[:cut]))
        if mapped is not None:
            return ROOT / mapped / Path(*parts[cut:])
    return ROOT / Path(*parts)


def assemble(dest: Path) -> Path:
    """Copy every package pyproject.toml lists to its import path under ``dest``; ``dest`` back."""
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    package_dir: dict[str, str] = setuptools.get("package-dir", {})
    for package in setuptools["packages"]:
        target = dest.joinpath(*package.split("."))
        target.mkdir(parents=True, exist_ok=True)
        for module in package_folder(package, package_dir).glob("*.py"):
            shutil.copy2(module, target / module.name)  # mtimes kept: mypy's cache stays valid
    shutil.copy2(ROOT / "pyproject.toml", dest / "pyproject.toml")
    # The driver interface's contract, which a plain lint-imports in the checkout cannot run.
    (dest / "drivers").mkdir(exist_ok=True)
    shutil.copy2(ROOT / DRIVER_CONTRACT, dest / DRIVER_CONTRACT)
    return dest


def console_script(name: str) -> Path | None:
    """The console script ``name`` of the environment this Python runs in, or None if it has none.

    Beside ``sys.executable`` (sysconfig's ``scripts``: a venv's ``bin/``), else in the user
    scheme's (``pip install --user``): never whichever ``name`` comes first on PATH, which in
    a venv that is not activated is another install's (or none).
    """
    schemes = [sysconfig.get_default_scheme()]
    if sys.prefix == sys.base_prefix:  # a venv: its own scripts only; outside one, --user's too
        schemes.append(f"{os.name}_user")
    for scheme in schemes:
        found = Path(sysconfig.get_path("scripts", scheme)) / name
        if found.is_file() and os.access(found, os.X_OK):
            return found
    return None


def run_installed(*argv: str, timeout_s: float = 900) -> subprocess.CompletedProcess[str]:
    """Run ``argv`` in an assembled tree on the import path; its file names as in the checkout."""
    with tempfile.TemporaryDirectory(prefix="compd-installed-") as tmp:
        tree = assemble(Path(tmp))
        env = {**os.environ, "PYTHONPATH": str(tree)}
        env.setdefault("MYPY_CACHE_DIR", str(ROOT / ".mypy_cache"))
        done = subprocess.run(
            argv, cwd=tree, env=env, capture_output=True, text=True, timeout=timeout_s
        )
    # A finding in compd/drivers/x.py of the tree is one in drivers/x.py of the checkout.
    done.stdout, done.stderr = (
        text.replace(f"{tree}{os.sep}", "").replace(
            f"compd{os.sep}drivers{os.sep}", f"drivers{os.sep}"
        )
        for text in (done.stdout, done.stderr)
    )
    return done


def main(argv: list[str]) -> int:
    """``python -m tests.installed TOOL [ARGS...]``: TOOL's output and exit status."""
    if not argv:
        print(__doc__, file=sys.stderr)
        return 2
    tool = str(console_script(argv[0]) or shutil.which(argv[0]) or argv[0])
    done = run_installed(tool, *argv[1:])
    sys.stdout.write(done.stdout)
    sys.stderr.write(done.stderr)
    return done.returncode


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
