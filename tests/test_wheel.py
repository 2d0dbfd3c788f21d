"""A plain (non-editable) install works: the wheel carries every module, scene and template, and ``ctr-bench run``
and ``ctr-bench report`` run from it.

Issue 14, item 7: ``ctr-bench run`` looked for scenes/paper.toml beside the
source tree, which an installed wheel does not have. This test builds the wheel
from a copy of the tree, installs it into a fresh virtual environment and runs
the console script from a directory outside the checkout.

The fresh environment borrows the dependencies of the interpreter running the
tests through a ``.pth`` line naming its site-packages. (``venv
--system-site-packages`` would not do: a venv made from a venv's python is based
on the base interpreter, whose site-packages are not .venv's.) A ``.pth`` line
only adds a path: the ``.pth`` files in that folder, among them the editable
install's finder that maps ``rig`` to the checkout, are not run, so the wheel's
``rig`` is the only one; the test checks that it is the one imported.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import site
import subprocess
import sys
import zipfile
from importlib.metadata import version
from pathlib import Path

import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
#: Build outputs and caches that a release never ships (rig/hw/firmware/build, rig/hw/sim/build are gitignored).
IGNORED = shutil.ignore_patterns("__pycache__", "*.pyc", "build", "*.egg-info")
#: pip's words when the build backend cannot be had (no index, none cached): building is impossible here.
NO_BACKEND = ("No matching distribution found for setuptools", "Could not find a version that satisfies the requirement setuptools")


def _source_copy(dest: Path) -> Path:
    """The files a wheel is built from (pyproject, README, the package and data folders), copied to ``dest``."""
    setup = PYPROJECT["tool"]["setuptools"]
    tops = {name.split(".")[0] for name in setup["packages"]} | set(setup.get("package-dir", {}).values())
    dest.mkdir()
    for name in ("pyproject.toml", PYPROJECT["project"]["readme"]):
        shutil.copy2(ROOT / name, dest / name)
    for top in sorted(tops):
        shutil.copytree(ROOT / top, dest / top, ignore=IGNORED)
    return dest


def _backend_installed() -> bool:
    """Whether this interpreter's setuptools meets ``[build-system] requires`` (then no index is needed)."""
    need = next((m.group(1) for r in PYPROJECT["build-system"]["requires"]
                 if (m := re.fullmatch(r"setuptools\s*>=\s*([\d.]+)", r.strip()))), "0")
    try:
        have = version("setuptools")
    except Exception:  # noqa: BLE001 - not installed at all
        return False

    def key(v: str) -> tuple:
        return tuple(int(p) for p in re.findall(r"\d+", v)[:3])

    return key(have) >= key(need)


def _build_wheel(src: Path, dist: Path) -> Path:
    """Build the wheel of ``src`` into ``dist``: offline with this interpreter's setuptools when it is recent
    enough, else in pip's isolated build environment (setuptools from the index); skip when neither can be had."""
    offline = _backend_installed()
    # an absolute path: a bare folder name is taken for a requirement and looked up in the index
    cmd = [sys.executable, "-m", "pip", "wheel", "--no-deps", *(["--no-build-isolation"] if offline else []),
           "-w", str(dist), str(src.resolve())]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=src.parent)
    out = proc.stdout + proc.stderr
    if proc.returncode != 0 and not offline and any(s in out for s in NO_BACKEND):
        pytest.skip(f"cannot build the wheel here: this interpreter's setuptools is older than "
                    f"{PYPROJECT['build-system']['requires']} and no package index offers a newer one")
    assert proc.returncode == 0, f"{' '.join(cmd)} failed:\n{out[-3000:]}"
    (wheel,) = dist.glob("ctr_bench-*.whl")
    return wheel


def _expected_members(src: Path) -> set:
    """Wheel paths of every file of the copied tree: packages as they are, the mapped data folders under their package."""
    setup = PYPROJECT["tool"]["setuptools"]
    folder_of = {folder: pkg.replace(".", "/") for pkg, folder in setup.get("package-dir", {}).items()}
    out = set()
    for path in src.rglob("*"):
        rel = path.relative_to(src).as_posix()
        top, _, rest = rel.partition("/")
        if path.is_file() and rest:
            out.add(f"{folder_of[top]}/{rest}" if top in folder_of else rel)
    return out


def _fresh_venv(where: Path, wheel: Path) -> Path:
    """A new venv with ``wheel`` installed and this interpreter's packages (the dependencies) behind it."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(where)], check=True, timeout=120)
    python = where / "bin" / "python"
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             capture_output=True, text=True, check=True).stdout.strip()
    # after the venv's own site-packages on sys.path, so the wheel's packages come first
    Path(purelib, "_ctr_bench_test_deps.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index", "--quiet",
                    str(wheel)], check=True, capture_output=True, text=True, timeout=300)
    return where


def _clean_env() -> dict:
    """The environment the console script runs in: no PYTHONPATH (or the like) that could reach the checkout."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSAFEPATH", "PYTHONSTARTUP")}
    env["PYTHONNOUSERSITE"] = "1"
    env["PYOPENGL_PLATFORM"] = os.environ.get("PYOPENGL_PLATFORM", "egl")  # as the rest of the suite renders
    return env


WHERE = """
import sys, importlib.metadata as md, recon, rig, twin
from rig.scenefiles import scenes_dir
print(rig.__file__, recon.__file__, twin.__file__, scenes_dir(), md.files("ctr-bench")[0].locate(), sep="\\n")
print("editable finder:", any("editable" in repr(f).lower() for f in sys.meta_path + sys.path_hooks))
"""


def _check_imports_from(venv: Path, cwd: Path, env: dict) -> None:
    """The venv's packages, scenes and metadata are the wheel's, not the checkout's (editable) ones."""
    proc = subprocess.run([str(venv / "bin" / "python"), "-c", WHERE], cwd=cwd, env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    *paths, finder = proc.stdout.strip().splitlines()
    for p in paths:
        assert Path(p).resolve().is_relative_to(venv.resolve()), (p, proc.stdout)
    assert finder == "editable finder: False", proc.stdout


def test_wheel_installs_and_runs_the_default_scene(tmp_path):
    src = _source_copy(tmp_path / "src")
    expected = _expected_members(src)  # before the build writes build/ and *.egg-info into src
    wheel = _build_wheel(src, tmp_path / "dist")
    members = {n for n in zipfile.ZipFile(wheel).namelist() if ".dist-info/" not in n}
    assert members == expected  # every module and scene file, nothing else
    assert {"rig/bench/templates/report.html.j2", "rig/bench/templates/report.css"} <= members  # the report's layout
    venv = _fresh_venv(tmp_path / "venv", wheel)
    elsewhere = tmp_path / "elsewhere"  # outside the checkout: nothing found through the working directory
    elsewhere.mkdir()
    env = _clean_env()
    _check_imports_from(venv, elsewhere, env)
    exe = str(venv / "bin" / "ctr-bench")

    proc = subprocess.run([exe, "--version"], cwd=elsewhere, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == f"ctr-bench {PYPROJECT['project']['version']}", proc

    # the cheapest run of the default scene: 1 robot frame, the 6 background frames the paper method needs
    cmd = [exe, "run", "--n-frames", "1", "--n-background-frames", "6", "--no-report", "--quiet", "--out", "r"]
    proc = subprocess.run(cmd, cwd=elsewhere, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert re.search(r"^frame\s+tip mm\s+mean mm\s+max mm\s+ms/pair\s+status$", proc.stdout, re.M), proc.stdout
    assert "method paper: 1 frames, 0 failed" in proc.stdout, proc.stdout
    scene = Path(json.loads((elsewhere / "r" / "session" / "session.json").read_text())["scene"])
    assert scene.resolve().parts[-3:] == ("rig", "scenes", "paper.toml"), scene  # the wheel's copy, not the checkout's
    assert scene.resolve().is_relative_to(venv.resolve()), scene

    # the report's template is found inside the installed package (jinja2's PackageLoader), not the checkout
    cmd = [exe, "report", "r", "--no-overlays", "--no-meshes", "--quiet"]
    proc = subprocess.run(cmd, cwd=elsewhere, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "<h2 id='summary'>Summary</h2>" in (elsewhere / "r" / "report" / "index.html").read_text()
