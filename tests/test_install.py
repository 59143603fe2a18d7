"""The installed package, as a user gets it from `pip install .`: built into a wheel, installed
into a fresh virtual environment and run through its `ooc-dem` console script from outside the
checkout (so nothing can be imported from the source tree by accident)."""

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _source_packages() -> set[str]:
    """Every importable package of the checkout: a directory of ooc_dem/ with an
    __init__.py."""
    return {".".join(p.parent.relative_to(REPO).parts) for p in (REPO / "ooc_dem").rglob("__init__.py")}


def test_the_wheel_holds_every_package_and_its_console_script_runs(tmp_path):
    # built from a copy, as `pip install .` builds it (an isolated build), so that no build/
    # or egg-info directory lands in the checkout
    src = tmp_path / "src"
    shutil.copytree(
        REPO,
        src,
        ignore=shutil.ignore_patterns(
            ".git", "__pycache__", "build", "*.egg-info", "runs", ".pytest_cache", ".hypothesis"
        ),
    )
    wheels = tmp_path / "wheels"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", wheels, src],
        check=True,
        capture_output=True,
        text=True,
        timeout=300,
    )
    (wheel,) = wheels.glob("ooc_dem-*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
    in_wheel = {n.rsplit("/", 1)[0].replace("/", ".") for n in names if n.endswith("/__init__.py")}
    assert _source_packages() <= in_wheel, f"packages missing from the wheel: {_source_packages() - in_wheel}"
    assert {"ooc_dem/scenarios/quick.toml", "ooc_dem/scenarios/quick-3d.toml"} <= names

    # installed into a directory of its own and put first on the path of this interpreter, so that
    # it sees this environment's dependencies whatever that is (a virtual environment or the bare
    # interpreter: a nested venv with system site-packages would see the base interpreter's, not
    # an outer venv's) and nothing of the checkout
    target = tmp_path / "installed"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--target", target, "-q", wheel],
        check=True,
        capture_output=True,
        text=True,
        timeout=300,
    )
    env = {**os.environ, "PYTHONPATH": str(target)}
    py = sys.executable
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    where = subprocess.run(
        [py, "-c", "import ooc_dem, ooc_dem.physics.d2, ooc_dem.physics.d3; print(ooc_dem.__file__)"],
        cwd=outside,
        env=env,
        check=True,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert Path(where.stdout.strip()).is_relative_to(target), where.stdout
    cp = subprocess.run(
        [target / "bin" / "ooc-dem", "scenarios"], cwd=outside, env=env, capture_output=True, text=True, timeout=300
    )
    assert cp.returncode == 0, cp.stderr[-3000:]
    listed = {ln.split()[0] for ln in cp.stdout.splitlines() if ln.strip()}
    assert {"quick", "paper2008", "quick-3d", "paper2008-3d", "bed3d"} <= listed, cp.stdout
