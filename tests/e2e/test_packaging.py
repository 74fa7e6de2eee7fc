"""``pip install .`` (issue 16): the wheel built from a clean copy of the checkout, installed in a
fresh venv, gives working ``fleet`` and ``edge-agent`` commands with the URDF, run outside the
checkout. No index is ever asked: the wheel is built with this venv's setuptools
(``--no-build-isolation``) and installed with ``--no-deps``; the new venv reaches the
dependencies through a ``.pth`` line naming this venv's site-packages, which adds that directory
only (its own ``.pth`` files, the editable install of the checkout among them, are not run)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from importlib.metadata import version
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("fleet", "edge_agent", "viewer")


def _run(argv: list[str], cwd: Path, timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    """Run with no PYTHONPATH and no pip configuration that could point at an index."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "PIP_"))}
    env.update(PIP_NO_INDEX="1", PIP_CONFIG_FILE=os.devnull, PIP_DISABLE_PIP_VERSION_CHECK="1")
    done = subprocess.run(
        argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout_s, check=False
    )
    assert done.returncode == 0, f"{' '.join(argv)}:\n{done.stdout}\n{done.stderr}"
    return done


def _clean_checkout(into: Path) -> list[str]:
    """Copy what git would check out (tracked and new files, nothing ignored: no .venv, no
    build/, no egg-info) into ``into``; return the relative paths."""
    if not (REPO / ".git").exists() or shutil.which("git") is None:
        pytest.skip("not a git checkout")
    listed = subprocess.run(
        ["git", "-C", str(REPO), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        capture_output=True,
        check=True,
        timeout=30,
    ).stdout.decode()
    files = [f for f in listed.split("\0") if f and (REPO / f).is_file()]
    for name in files:
        (into / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / name, into / name)
    return files


def test_wheel_installs_working_commands_with_their_data(tmp_path: Path) -> None:
    have = version("setuptools")
    if int(have.split(".")[0]) < 77:
        pytest.fail(f"setuptools {have} here; the [test] extra asks for >=77 (pyproject's build)")
    src, dist, venv, elsewhere = (tmp_path / d for d in ("src", "dist", "venv", "elsewhere"))
    for d in (src, dist, elsewhere):
        d.mkdir()
    files = _clean_checkout(src)
    _run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index"]
        + ["-q", "-w", str(dist), str(src)],
        cwd=tmp_path,
    )
    (wheel,) = dist.glob("d1_fleet-*.whl")
    # Every non-Python file of our packages is in the wheel (package-data keeps up with assets).
    data = {f for f in files if f.split("/")[0] in PACKAGES and not f.endswith(".py")}
    assert data, "no package data found: the URDF should be one"
    names = zipfile.ZipFile(wheel).namelist()
    missing = data - set(names)
    assert not missing, f"add to [tool.setuptools.package-data] in pyproject.toml: {missing}"
    # Only the product ships: no benchmark tool, test helper or fuzz target (bench/, testkit/,
    # tests/, fuzz/ are the checkout's), not even one hiding inside a product package.
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert tops == set(PACKAGES), f"the wheel ships {sorted(tops)}, not only {PACKAGES}"
    tools = [n for n in names if n.rpartition("/")[2].startswith(("bench", "synthetic", "test"))]
    assert tools == [], f"benchmark and test tools belong in bench/ or testkit/: {tools}"

    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], cwd=tmp_path)
    python = venv / "bin" / "python"
    _run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-deps"]
        + ["--no-index", str(wheel)],
        cwd=tmp_path,
    )
    site = Path(
        _run(
            [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            cwd=elsewhere,
        ).stdout.strip()
    )
    (site / "d1_fleet_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")

    assert _run([str(venv / "bin" / "fleet"), "--version"], cwd=elsewhere).stdout.strip() == (
        f"fleet {version('d1-fleet')}"
    )
    schema = json.loads(_run([str(venv / "bin" / "fleet"), "schema"], cwd=elsewhere).stdout)
    assert schema, "fleet schema printed nothing"
    assert "--interface" in _run([str(venv / "bin" / "edge-agent"), "--help"], cwd=elsewhere).stdout
    check = (
        "import sys, fleet, edge_agent, viewer\n"
        "from fleet.scene3d.kinematics import URDF_PATH, load_urdf\n"
        "print(json.dumps({'paths': [fleet.__file__, edge_agent.__file__, viewer.__file__,\n"
        "    str(URDF_PATH)], 'sys_path': sys.path, 'links': len(load_urdf().link_map)}))\n"
    )
    found = json.loads(_run([str(python), "-c", "import json\n" + check], cwd=elsewhere).stdout)
    assert all(p.startswith(str(site)) for p in found["paths"]), found["paths"]
    assert str(REPO) not in found["sys_path"] and str(src) not in found["sys_path"]
    assert found["links"] > 5
