"""The render cache: a twin scene is rendered once and its session reused by every command that needs it.

One owner for the cache that ``run``, ``bench`` (one scene, ``--scaling``,
``--suite wide``), ``tune`` and ``dataset`` share. A cached session lives in
``CACHE_DIR/<scene>-<width>x<height>-<key>``; the key (:func:`cache_key`) is a
hash of everything the rendered images depend on:

* the scene file's bytes (not its path: two copies of a file share a render);
* the frame counts (``--n-frames``, ``--n-background-frames``), the kinematic
  model (``--model``) and the image scale;
* the twin's own source (``twin/**/*.py``, :func:`code_digest`): a change to the renderer, the noise or
  the kinematics renders again instead of serving images the code no longer makes.

A session is rendered under a temporary name and renamed when complete, so an
interrupted render is never taken for a cached one; a cached session that no
longer opens, or holds fewer frames than the scene, is rendered again.
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import shutil
import sys
from dataclasses import replace
from pathlib import Path

from recon.rigcal import RigCalibration
from rig.bench.cores import pin_worker
from rig.bench.scenes import render_scene_to
from rig.session import Session, SessionError
from twin.scene import load_scene

__all__ = ["DEFAULT_CACHE_DIR", "scaled_scene", "code_digest", "cache_key", "cached_session", "link_session", "render_into_cache"]

#: Where rendered sessions are cached unless a command's ``--cache-dir`` says otherwise
#: (``run``, ``bench``, ``dataset``; ``bench --suite`` and ``dataset`` use its ``sessions/``).
DEFAULT_CACHE_DIR = Path("out") / "bench-cache"


def scaled_scene(scene, factor: float):
    """The scene with every camera's image ``factor`` times larger (same field of view)."""
    if factor == 1:
        return scene

    rig = scene.rig
    cams = {n: c.scaled(factor) for n, c in rig.cameras.items()}
    new_rig = RigCalibration(cameras=cams, base_point_world_mm=rig.base_point_world_mm, insertion_axis_world=rig.insertion_axis_world)
    return replace(scene, rig=new_rig)


_CODE_DIGESTS: dict = {}


def code_digest(*packages: str) -> str:
    """Hash (hex) of the Python sources of ``packages`` (e.g. ``"twin"``), read once per process.

    What a cached result depends on besides its inputs: the render cache keys renders by the
    twin's code, and sweeps (:func:`rig.bench.sweep.task_digest`) their results by recon/,
    twin/ and rig/.

    Parameters
    ----------
    *packages : str
        Importable package names.

    Returns
    -------
    str
        SHA-256 of every ``*.py`` file's path and bytes, package by package, files sorted.
    """
    if packages not in _CODE_DIGESTS:
        h = hashlib.sha256()
        for name in packages:
            spec = importlib.util.find_spec(name)
            for folder in (spec.submodule_search_locations or []) if spec else []:
                for path in sorted(Path(folder).rglob("*.py")):
                    h.update(f"{name}/{path.relative_to(folder)}".encode() + b"\0" + path.read_bytes() + b"\0")
        _CODE_DIGESTS[packages] = h.hexdigest()
    return _CODE_DIGESTS[packages]


def cache_key(scene, factor: float = 1.0) -> str:
    """Hash of what the rendered session depends on: the scene file, frame counts, model, image scale, the twin's code."""
    h = hashlib.sha256()
    try:
        h.update(Path(scene.source).read_bytes())
    except OSError:
        h.update(scene.source.encode())
    h.update(f"|frames={len(scene.joints)}|bg={scene.background_frames}|scale={factor:g}|model={scene.model}".encode())
    h.update(f"|twin={code_digest('twin')}".encode())
    return h.hexdigest()[:12]


def _complete(path: Path, n_frames: int) -> bool:
    if not (path / "session.json").exists():
        return False
    try:
        return len(Session(path).frames) == n_frames
    except SessionError:
        return False


def cached_session(scene, factor: float = 1.0, cache_dir: Path = DEFAULT_CACHE_DIR, quiet: bool = True, log=None) -> Path:
    """A rendered session of ``scene`` at image scale ``factor``, rendered into ``cache_dir`` on first use.

    Parameters
    ----------
    scene : twin.scene.Scene
    factor : float
        Image scale (:func:`scaled_scene`).
    cache_dir : path
    quiet : bool
        No per-frame progress bars while rendering.
    log : callable, optional
        Called with one line when the scene is rendered (default: printed to stderr).

    Returns
    -------
    Path
        The session directory (``cache_dir/<scene>-<W>x<H>-<key>``).
    """
    cache_dir = Path(cache_dir)
    sc = scaled_scene(scene, factor)
    cam0 = sc.rig[sc.rig.names[0]]
    out = cache_dir / f"{scene.name}-{cam0.width}x{cam0.height}-{cache_key(scene, factor)}"
    if _complete(out, len(sc.joints)):
        return out
    shutil.rmtree(out, ignore_errors=True)
    tmp = out.with_name(out.name + f".tmp{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.parent.mkdir(parents=True, exist_ok=True)
    line = f"rendering {scene.name!r} at {cam0.width}x{cam0.height} ({len(sc.joints)} frames) into {out} (cached for later runs)"
    (log or (lambda text: print(text, file=sys.stderr)))(line)
    try:
        render_scene_to(sc, tmp, quiet=quiet)
        os.replace(tmp, out)
    except OSError:
        if not _complete(out, len(sc.joints)):  # not another process that cached the same render meanwhile
            raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def link_session(src: Path, dst: Path) -> Path:
    """``dst`` as a copy of the session ``src`` made of hard links (copies across file systems); returns ``dst``.

    The files are shared, not duplicated: nothing rewrites a session's files in
    place (they are written under temporary names and renamed), so removing or
    replacing ``dst`` leaves the cached session as it was.
    """
    def link(a, b):
        try:
            os.link(a, b)
        except OSError:
            shutil.copy2(a, b)

    dst = Path(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_name(f".{dst.name}.tmp{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(src, tmp, copy_function=link)
    os.replace(tmp, dst)
    return dst


def render_into_cache(scene_file, cache_dir) -> dict:
    """A sweep task: render one scene file into ``cache_dir`` (nothing when it is cached).

    Returns ``{"scene", "session", "frames"}``: the file, the cached session directory and its frame count.
    """
    pin_worker()
    scene = load_scene(scene_file)
    return {"scene": str(scene_file), "session": str(cached_session(scene, 1.0, Path(cache_dir))), "frames": len(scene.joints)}
