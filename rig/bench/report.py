"""The report of a reconstruction run: ``OUT/report/index.html`` with PNG figures.

``ctr-bench run`` and ``ctr-bench reconstruct`` build it at the end (``--no-report``
skips it); ``ctr-bench report OUT`` rebuilds it from what the run wrote
(the files ``summary.json`` lists: ``backbones.npz`` or the per-frame CSVs, the journal
of a run cut short; and, when it can be found, the session with its images, calibration
and ground truth). Everything is static: HTML with relative links
to PNGs, no JavaScript, no network. Contents and file names: docs/outputs.md.

The figure functions take arrays and write one PNG each (matplotlib's Agg canvas,
never pyplot, so no global backend is touched); :func:`build_report` gathers the
arrays from a run directory and writes the page, whose layout is the jinja2 template
``rig/bench/templates/report.html.j2`` (the functions here compute its rows and numbers).
"""
from __future__ import annotations

import functools
import json
import os
import shutil
import sys
import time
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from matplotlib import cm, colors
from matplotlib.colors import LightSource
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Poly3DCollection
from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape
from PIL import Image, ImageDraw, ImageFont

from recon.geometry import arc_length, closest_arc_length
from recon.rigcal import load_rig_calibration
from recon.tubemesh import radii_along, tube_mesh
from rig.bench.meshes import recon_tube, truth_tube, write_frame_meshes
from rig.rundir import read_run
from rig.session import read_image
from rig.session_checks import TruthError, check_truth

__all__ = [
    "build_report",
    "load_run",
    "RunData",
    "time_colors",
    "fig_backbones_3d",
    "fig_projections",
    "fig_error_along_arc",
    "fig_errors_per_frame",
    "fig_timing",
    "fig_tubes",
    "overlay_panels",
    "frame_overlay",
    "save_png",
    "select_detail_frames",
    "MAX_DETAIL_FRAMES",
    "MAX_MESH_FRAMES",
]

#: Frames shown one by one (overlays) at most; beyond, a selection (failed, worst, evenly spaced).
MAX_DETAIL_FRAMES = 50
#: Tube meshes are written for every frame of runs with at most this many frames (more: ``--meshes``).
MAX_MESH_FRAMES = 50

# Okabe-Ito colours: readable by colour-blind readers, distinct on grey camera images.
RECON_RGB = (0, 114, 178)
TRUTH_RGB = (230, 159, 0)
FAIL_RGB = (213, 94, 0)
_RECON = tuple(c / 255 for c in RECON_RGB)
_TRUTH = tuple(c / 255 for c in TRUTH_RGB)
_FAIL = tuple(c / 255 for c in FAIL_RGB)
_DPI = 100


# ----------------------------------------------------------------------------- helpers
def save_png(fig: Figure, path) -> Path:
    """Save a matplotlib figure as PNG (palette-quantized when that loses nothing visible)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=_DPI, facecolor="white")
    _shrink_png(path)
    return path


def _shrink_png(path: Path, colours: int = 256) -> None:
    """Re-encode a PNG with an adaptive palette (plots use few colours; 3-4x smaller)."""
    img = Image.open(path).convert("RGB")
    img.quantize(colors=colours, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(path, compress_level=6)


def time_colors(t, lo: float = 0.95, hi: float = 0.35) -> np.ndarray:
    """Fig. 8 colours: dark blue for the first frame to light blue for the last (RGBA rows)."""
    t = np.asarray(t, dtype=np.float64)
    span = np.ptp(t) if t.size else 0.0
    u = (t - t.min()) / span if span > 0 else np.zeros_like(t)
    return cm.Blues(lo + (hi - lo) * u)


def _time_mappable(t, lo=0.95, hi=0.35):
    t = np.asarray(t, dtype=np.float64)
    vmin, vmax = (float(t.min()), float(t.max())) if t.size else (0.0, 1.0)
    if vmax <= vmin:
        vmax = vmin + 1.0
    cmap = colors.LinearSegmentedColormap.from_list("fig8", cm.Blues(np.linspace(lo, hi, 256)))
    return cm.ScalarMappable(norm=colors.Normalize(vmin, vmax), cmap=cmap)


def _set_axes_equal_3d(ax, pts: np.ndarray, pad: float = 0.05, min_frac: float = 0.2, zoom: float = 1.0) -> None:
    """Equal mm on the three axes; an axis with a flat spread keeps ``min_frac`` of the longest."""
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    c = (lo + hi) / 2
    span = np.maximum(hi - lo, 1e-6) * (1 + 2 * pad)
    span = np.maximum(span, max(float(span.max()) * min_frac, 1.0))
    ax.set_xlim(c[0] - span[0] / 2, c[0] + span[0] / 2)
    ax.set_ylim(c[1] - span[1] / 2, c[1] + span[1] / 2)
    ax.set_zlim(c[2] - span[2] / 2, c[2] + span[2] / 2)
    ax.set_box_aspect(tuple(span), zoom=zoom)
    for a in (ax.xaxis, ax.yaxis, ax.zaxis):
        a.set_major_locator(MaxNLocator(5 if a is ax.xaxis else 3))


def _px_axis(ax, mm_per_px, which="y"):
    """A secondary axis in pixels (at the robot base) next to an axis in mm."""
    if not mm_per_px or not np.isfinite(mm_per_px) or mm_per_px <= 0:
        return
    k = float(mm_per_px)
    if which == "y":
        sec = ax.secondary_yaxis("right", functions=(lambda v: v / k, lambda v: v * k))
        sec.set_ylabel(f"px (1 px = {k:.3f} mm)")
    else:
        sec = ax.secondary_xaxis("top", functions=(lambda v: v / k, lambda v: v * k))
        sec.set_xlabel(f"px (1 px = {k:.3f} mm)")


# ----------------------------------------------------------------------------- figures
def fig_backbones_3d(path, backbones: list, times, truths: list | None = None, base_mm=None, title: str | None = None) -> Path:
    """Fig. 8 of the paper: every reconstructed backbone in 3D, dark to light blue with time.

    Parameters
    ----------
    backbones : list of (n_i, 3) arrays (world mm), one per frame
    times : (len(backbones),) frame times (s)
    truths : list of (m_i, 3) arrays or None, optional
        Ground truth per frame, drawn dashed in the frame's colour.
    base_mm : (3,) array, optional
        Robot base, drawn as a black square.
    """
    fig = Figure(figsize=(9.0, 5.6))
    ax = fig.add_axes((0.0, 0.12, 1.0, 0.84), projection="3d")
    col = time_colors(times)
    allpts = []
    for i, b in enumerate(backbones):
        b = np.asarray(b, float).reshape(-1, 3)
        if len(b):
            ax.plot(b[:, 0], b[:, 1], b[:, 2], color=col[i], lw=2.2, solid_capstyle="round")
            allpts.append(b)
        tr = truths[i] if truths is not None else None
        if tr is not None:
            ax.plot(tr[:, 0], tr[:, 1], tr[:, 2], color=col[i], lw=1.0, ls=(0, (4, 3)), alpha=0.9)
            allpts.append(tr)
    if base_mm is not None:
        ax.plot(*np.asarray(base_mm, float).reshape(3, 1), "s", color="black", ms=6)
        allpts.append(np.asarray(base_mm, float).reshape(1, 3))
    if allpts:
        _set_axes_equal_3d(ax, np.concatenate(allpts), zoom=1.35)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.view_init(elev=38, azim=-72)
    ax.set_proj_type("ortho")
    handles = [
        _line2d(color=cm.Blues(0.7), lw=2.2, label="reconstruction"),
    ]
    if truths is not None and any(t is not None for t in truths):
        handles.append(_line2d(color=cm.Blues(0.7), lw=1.0, ls=(0, (4, 3)), label="ground truth"))
    if base_mm is not None:
        handles.append(_line2d(color="black", marker="s", ls="none", label="robot base"))
    ax.legend(handles=handles, loc="upper left", fontsize=9, frameon=False)
    _time_colorbar(fig, times)
    fig.suptitle(title or "Backbones over time (dark: first frame, light: last)", fontsize=11, y=0.98)
    return save_png(fig, path)


def _time_colorbar(fig, times) -> None:
    """A horizontal time colour bar along the bottom of a 3D figure."""
    if len(times):
        cax = fig.add_axes((0.3, 0.1, 0.4, 0.025))
        cb = fig.colorbar(_time_mappable(times), cax=cax, orientation="horizontal")
        cb.set_label("time (s)", fontsize=9)
        cb.ax.tick_params(labelsize=8)


def _line2d(**kw):
    return Line2D([], [], **kw)


def fig_projections(path, backbones: list, times, truths: list | None = None, base_mm=None) -> Path:
    """Two orthographic views of all backbones: top (x-y) and side (x-z), same mm scale on every axis."""
    allp = [np.asarray(b, float).reshape(-1, 3) for b in backbones] + [t for t in (truths or []) if t is not None]
    if base_mm is not None:
        allp.append(np.asarray(base_mm, float).reshape(1, 3))
    P = np.concatenate(allp) if allp else np.zeros((1, 3))
    lo, hi = P.min(axis=0), P.max(axis=0)
    xspan = max(hi[0] - lo[0], 10.0) * 1.08
    pads = [max(hi[j] - lo[j], 0.12 * xspan) * 1.15 for j in range(3)]
    heights = [pads[1], pads[2]]
    fig = Figure(figsize=(10.0, 1.6 + 8.4 * min(1.0, sum(heights) / xspan)))
    axes = fig.subplots(2, 1, gridspec_kw={"height_ratios": heights})
    col = time_colors(times)
    for ax, (j, name) in zip(axes, [(1, "top view (x-y)"), (2, "side view (x-z)")]):
        for i, b in enumerate(backbones):
            b = np.asarray(b, float).reshape(-1, 3)
            tr = truths[i] if truths is not None else None
            if tr is not None:
                ax.plot(tr[:, 0], tr[:, j], color=col[i], lw=1.0, ls=(0, (4, 3)))
            if len(b):
                ax.plot(b[:, 0], b[:, j], color=col[i], lw=2.0, solid_capstyle="round")
                ax.plot(b[-1, 0], b[-1, j], "o", color=col[i], ms=3.5)
        if base_mm is not None:
            base = np.asarray(base_mm, float).reshape(3)
            ax.plot(base[0], base[j], "s", color="black", ms=5)
        cx, cj = (lo[0] + hi[0]) / 2, (lo[j] + hi[j]) / 2
        ax.set_xlim(cx - xspan / 2, cx + xspan / 2)
        ax.set_ylim(cj - pads[j] / 2, cj + pads[j] / 2)
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel(("y" if j == 1 else "z") + " (mm)")
        ax.set_title(name, fontsize=11, loc="left")
        ax.grid(True, lw=0.4, alpha=0.5)
    handles = [_line2d(color=cm.Blues(0.7), lw=2.0, label="reconstruction (dot: tip)")]
    if truths is not None and any(t is not None for t in truths):
        handles.append(_line2d(color=cm.Blues(0.7), lw=1.0, ls=(0, (4, 3)), label="ground truth"))
    if base_mm is not None:
        handles.append(_line2d(color="black", marker="s", ls="none", label="robot base"))
    axes[0].legend(handles=handles, loc="upper left", fontsize=8)
    if len(times):
        cb = fig.colorbar(_time_mappable(times), ax=list(axes), shrink=0.9, pad=0.02, aspect=30)
        cb.set_label("time (s)")
    return save_png(fig, path)


def fig_error_along_arc(path, curves: list, times, mm_per_px=None) -> Path:
    """Closest-point distance of each reconstructed point to the true backbone vs arc length.

    Parameters
    ----------
    curves : list of (s_mm, d_mm) pairs, one per scored frame
        ``d_mm`` the distance of each reconstructed point to the true backbone polyline,
        ``s_mm`` the arc length (from the robot base) of that closest true point: where
        along the robot the point is (a stretch with no line was not reconstructed).
    times : frame times (s), for the colours
    """
    fig = Figure(figsize=(9.0, 4.6))
    ax = fig.add_subplot()
    col = time_colors(times)
    for i, (s, d) in enumerate(curves):
        o = np.argsort(s, kind="stable")
        s, d = np.asarray(s)[o], np.asarray(d)[o]
        gap = np.flatnonzero(np.diff(s) > 3.0)  # do not draw across stretches with no reconstructed point
        s, d = np.insert(s, gap + 1, np.nan), np.insert(d, gap + 1, np.nan)
        ax.plot(s, d, color=col[i], lw=1.4, marker=".", ms=2.5)
    if len(curves) >= 3:  # the median over frames, per 1 mm of arc length
        s_all = np.concatenate([np.asarray(c[0]) for c in curves])
        d_all = np.concatenate([np.asarray(c[1]) for c in curves])
        edges = np.arange(np.floor(s_all.min()), np.ceil(s_all.max()) + 1.0, 1.0)
        k = np.clip(np.digitize(s_all, edges) - 1, 0, max(len(edges) - 2, 0))
        med = np.array([np.median(d_all[k == i]) if np.any(k == i) else np.nan for i in range(max(len(edges) - 1, 1))])
        ax.plot((edges[:-1] + 0.5)[: len(med)], med, color="black", lw=2.2, label="median over frames (1 mm bins)")
        ax.legend(fontsize=9, loc="upper center")
    if curves:
        top = max(float(np.max(d)) if len(d) else 0.0 for _, d in curves)
        ax.set_ylim(0, max(top * 1.05, 0.05))
        cb = fig.colorbar(_time_mappable(times), ax=ax, pad=0.12)
        cb.set_label("time (s)")
    else:
        ax.text(0.5, 0.5, "no scored frames", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("arc length along the true backbone, from the robot base (mm)")
    ax.set_ylabel("distance to the true backbone (mm)")
    ax.set_title("Error along the backbone (one line per frame)", fontsize=11)
    ax.grid(True, lw=0.4, alpha=0.5)
    _px_axis(ax, mm_per_px)
    fig.tight_layout()
    return save_png(fig, path)


def fig_errors_per_frame(path, frames, mean_mm, max_mm, tip_mm, failed_frames=(), mm_per_px=None) -> Path:
    """Mean, max (Hausdorff) and tip error per frame; failed frames marked on the axis."""
    fig = Figure(figsize=(9.0, 4.4))
    ax = fig.add_subplot()
    f = np.asarray(frames, float)
    for vals, lab, st in ((max_mm, "max (Hausdorff)", dict(color="0.35", marker="v", ls=":")),
                          (mean_mm, "mean", dict(color=_RECON, marker="o", ls="-")),
                          (tip_mm, "tip", dict(color=_TRUTH, marker="D", ls="--"))):
        v = np.array([np.nan if x is None else x for x in vals], float)
        if np.any(np.isfinite(v)):
            ax.plot(f, v, lw=1.3, ms=4, label=lab, **st)
    if len(failed_frames):
        ax.plot(failed_frames, np.zeros(len(failed_frames)), "x", color=_FAIL, ms=9, mew=2, label="failed frame", clip_on=False)
    ax.set_ylim(bottom=0)
    ax.set_xlabel("frame")
    ax.set_ylabel("error (mm)")
    ax.set_title("Errors per frame", fontsize=11)
    ax.grid(True, lw=0.4, alpha=0.5)
    if len(f) and len(f) <= 40:
        ax.set_xticks(f)
        ax.tick_params(axis="x", labelsize=8)
    ax.legend(fontsize=9, loc="upper left")
    _px_axis(ax, mm_per_px)
    fig.tight_layout()
    return save_png(fig, path)


def fig_timing(path, ms, stage_ms: dict | None = None) -> Path:
    """Histogram of ms per pair and, when the method reports it, the time of each stage.

    Parameters
    ----------
    ms : (n,) array
        Wall time per frame pair (ms).
    stage_ms : dict stage -> (n,) array, optional
        ``timings_ms`` of the frames (a ``total`` entry is left out of the breakdown).
    """
    ms = np.asarray(ms, float)
    stages = {k: np.asarray(v, float) for k, v in (stage_ms or {}).items() if k != "total" and len(v)}
    fig = Figure(figsize=(11.0 if stages else 6.5, 4.2))
    axes = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1, 1.1]}) if stages else [fig.add_subplot()]
    ax = axes[0]
    if ms.size:
        bins = min(30, max(5, int(np.sqrt(ms.size)) * 2))
        ax.hist(ms, bins=bins, color=_RECON, alpha=0.85, edgecolor="white")
        med, p95 = np.median(ms), np.percentile(ms, 95)
        ax.axvline(med, color="black", lw=1.2, label=f"median {med:.1f} ms")
        ax.axvline(p95, color=_FAIL, lw=1.2, ls="--", label=f"p95 {p95:.1f} ms")
        ax.legend(fontsize=9)
    else:
        ax.text(0.5, 0.5, "no timed frames", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("ms per frame pair (one core)")
    ax.set_ylabel("frames")

    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_title("Time per pair", fontsize=11)
    if stages:
        ax2 = axes[1]
        names = list(stages)
        med = np.array([np.median(stages[k]) for k in names])
        p95 = np.array([np.percentile(stages[k], 95) for k in names])
        y = np.arange(len(names))[::-1]
        ax2.barh(y, med, color=_RECON, alpha=0.85, label="median")
        ax2.errorbar(med, y, xerr=[np.zeros_like(med), np.maximum(p95 - med, 0)], fmt="none", ecolor="0.3", capsize=3, label="to p95")
        total = med.sum()
        for yi, m, q in zip(y, med, p95):
            ax2.text(max(m, q), yi, f"  {m:.1f} ms ({100 * m / total:.0f}%)" if total > 0 else "", va="center", fontsize=8)
        ax2.set_yticks(y)
        ax2.set_yticklabels(names)
        ax2.set_xlabel("ms (median over frames; whisker: p95)")
        ax2.set_xlim(0, max(p95.max(), med.max()) * 1.45 + 1e-9)
        ax2.set_title("Per stage", fontsize=11)
    fig.tight_layout()
    return save_png(fig, path)


def _tube_polys(vertices, faces):
    return np.asarray(vertices)[np.asarray(faces)]


def fig_tubes(path, panels: list, titles: list | None = None, over_time: tuple | None = None) -> Path:
    """Rendered tube meshes: reconstruction (blue) and truth (orange) on the same axes.

    Parameters
    ----------
    panels : list of (recon, truth) pairs
        Each a ``(vertices, faces)`` tuple (world mm) or None; one 3D panel per pair.
    titles : list of str, optional
    over_time : (list of (vertices, faces), times), optional
        Instead of panels: every reconstruction in one view, dark to light blue with
        time (the paper's Fig. 8 as tubes).
    """
    ls = LightSource(azdeg=225, altdeg=45)
    if over_time is not None:
        meshes, times = over_time
        fig = Figure(figsize=(9.0, 5.6))
        ax = fig.add_axes((0.0, 0.12, 1.0, 0.84), projection="3d")
        col = time_colors(times)
        pts = []
        for (v, f), c in zip(meshes, col):
            ax.add_collection3d(Poly3DCollection(_tube_polys(v, f), facecolors=c, linewidths=0, shade=True, lightsource=ls))
            pts.append(v)
        if pts:
            _set_axes_equal_3d(ax, np.concatenate(pts), zoom=1.35)
        ax.view_init(elev=38, azim=-72)
        ax.set_proj_type("ortho")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_zlabel("z (mm)")
        fig.suptitle("Reconstructed tubes over time (dark: first frame, light: last)", fontsize=11, y=0.98)
        _time_colorbar(fig, times)
        return save_png(fig, path)
    n = len(panels)
    ncol = min(2, max(1, n))
    nrow = int(np.ceil(n / ncol)) if n else 1
    fig = Figure(figsize=(6.2 * ncol, 2.9 * nrow + 0.5))
    for k, (rec, tru) in enumerate(panels):
        ax = fig.add_subplot(nrow, ncol, k + 1, projection="3d")
        ax.computed_zorder = False  # always: reconstruction, then the translucent truth over it
        pts = []
        for z, (mesh, c, a) in enumerate(((rec, _RECON, 1.0), (tru, _TRUTH, 0.45))):
            if mesh is None:
                continue
            ax.add_collection3d(Poly3DCollection(_tube_polys(*mesh), facecolors=c, alpha=a, linewidths=0, shade=True, lightsource=ls, zorder=z + 1))
            pts.append(mesh[0])
        if pts:
            _set_axes_equal_3d(ax, np.concatenate(pts), zoom=1.35)
        ax.view_init(elev=38, azim=-72)
        ax.set_proj_type("ortho")
        ax.tick_params(labelsize=7)
        ax.set_xlabel("x (mm)", fontsize=8)
        ax.set_ylabel("y (mm)", fontsize=8)
        ax.set_zlabel("z (mm)", fontsize=8)
        if titles:
            ax.set_title(titles[k], fontsize=10)
    both = tuple(0.45 * np.array(_TRUTH) + 0.55 * np.array(_RECON))
    handles = [_line2d(color=_RECON, lw=6, label="reconstruction"), _line2d(color=_TRUTH, lw=6, alpha=0.45, label="ground truth (translucent, drawn over)"),
               _line2d(color=both, lw=6, label="both")]
    fig.legend(handles=handles, loc="lower center", ncol=3, fontsize=10, frameon=False)
    fig.subplots_adjust(left=0.0, right=1.0, top=0.96, bottom=0.5 / (2.9 * nrow + 0.5), wspace=0.0, hspace=0.0)
    return save_png(fig, path)


# ----------------------------------------------------------------------------- overlays
def _font(size: int):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1
        return ImageFont.load_default()


def _crop_box(pts: np.ndarray, w: int, h: int, pad: float, aspect: float, min_w: float) -> tuple:
    """A box (x0, y0, x1, y1) around ``pts`` with padding and aspect w/h, inside the image where possible.

    Box edges are continuous image coordinates: the image spans [-0.5, w - 0.5] x [-0.5, h - 0.5].
    """
    pts = pts[np.all(np.isfinite(pts), axis=1)] if len(pts) else pts
    if len(pts) == 0:
        return -0.5, -0.5, w - 0.5, h - 0.5
    lo = np.clip(pts.min(axis=0), -0.5, [w - 0.5, h - 0.5])
    hi = np.clip(pts.max(axis=0), -0.5, [w - 0.5, h - 0.5])
    c = (lo + hi) / 2
    bw = max(hi[0] - lo[0] + 2 * pad, (hi[1] - lo[1] + 2 * pad) * aspect, min_w)
    bw = min(bw, w, h * aspect)
    bh = bw / aspect
    x0 = float(np.clip(c[0] - bw / 2, -0.5, w - 0.5 - bw))
    y0 = float(np.clip(c[1] - bh / 2, -0.5, h - 0.5 - bh))
    return x0, y0, x0 + bw, y0 + bh


def _to_panel(uv, box, scale) -> np.ndarray:
    """Image pixel coordinates -> panel pixel coordinates (box edge at -0.5 on both)."""
    return (np.asarray(uv, float) - [box[0], box[1]]) * scale - 0.5


def _draw_polyline(img, uv, box, scale, rgb, thickness, dots=False):
    if uv is None or len(uv) == 0:
        return
    p = _to_panel(uv, box, scale)
    ok = np.all(np.isfinite(p), axis=1) & np.all(np.abs(p) < 1e5, axis=1)
    shift = 4
    q = np.where(ok[:, None], p, 0) * (1 << shift)
    q = np.round(q).astype(np.int32)
    # one polyline per run of drawable points
    breaks = np.flatnonzero(~ok)
    for seg in np.split(np.arange(len(p)), breaks):
        seg = seg[ok[seg]]
        if len(seg) == 0:
            continue
        arr = q[seg].reshape(-1, 1, 2)
        cv2.polylines(img, [arr], False, rgb, thickness, cv2.LINE_AA, shift)
        if dots:
            for pt in arr[:, 0]:
                cv2.circle(img, (int(pt[0]), int(pt[1])), 2 << shift, rgb, -1, cv2.LINE_AA, shift)


def _marker(img, uv, box, scale, rgb, kind: str, size: int = 7):
    if uv is None or not np.all(np.isfinite(uv)):
        return
    x, y = _to_panel(np.asarray(uv, float).reshape(1, 2), box, scale)[0]
    if max(abs(x), abs(y)) > 1e5:
        return
    x, y = int(round(x)), int(round(y))
    if kind == "circle":
        cv2.circle(img, (x, y), size, rgb, 2, cv2.LINE_AA)
    else:
        cv2.line(img, (x - size, y - size), (x + size, y + size), rgb, 2, cv2.LINE_AA)
        cv2.line(img, (x - size, y + size), (x + size, y - size), rgb, 2, cv2.LINE_AA)


def _panel(image: np.ndarray, box, out_w: int, out_h: int, recon_uv, truth_uv, zoom: bool) -> np.ndarray:
    """Crop ``box`` of ``image`` scaled to out_w x out_h, with the two curves drawn on it."""
    x0, y0, x1, y1 = box
    scale = out_w / (x1 - x0)
    border = dict(borderMode=cv2.BORDER_CONSTANT, borderValue=(40, 40, 40))
    if scale < 1:  # area-average the whole image first (no aliasing of the sensor noise), then crop
        small = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        M = np.array([[1.0, 0.0, -scale * (x0 + 0.5)], [0.0, 1.0, -scale * (y0 + 0.5)]])
        panel = cv2.warpAffine(small, M, (out_w, out_h), flags=cv2.INTER_LINEAR, **border)
    else:
        M = np.array([[scale, 0.0, -scale * x0 - 0.5], [0.0, scale, -scale * y0 - 0.5]])
        panel = cv2.warpAffine(image, M, (out_w, out_h), flags=cv2.INTER_CUBIC, **border)
    panel = np.ascontiguousarray(panel)
    # truth: wider and 70 % opaque, under the reconstruction: an orange rim on both sides of the
    # blue line means they agree; the image stays visible through it
    layer = panel.copy()
    _draw_polyline(layer, truth_uv, box, scale, TRUTH_RGB, 5 if zoom else 4)
    panel = cv2.addWeighted(layer, 0.7, panel, 0.3, 0.0)
    _draw_polyline(panel, recon_uv, box, scale, RECON_RGB, 2, dots=zoom)
    if truth_uv is not None and len(truth_uv):
        _marker(panel, truth_uv[-1], box, scale, TRUTH_RGB, "cross", 8 if zoom else 6)
    if recon_uv is not None and len(recon_uv):
        _marker(panel, recon_uv[-1], box, scale, RECON_RGB, "circle", 8 if zoom else 6)
    return panel


def _camera_row(img: np.ndarray, cam: str, ru, tu, view_width: int, aspect_range, tip_min_px: float, font) -> np.ndarray:
    """One camera's row of :func:`overlay_panels`: the robot region and the square tip zoom, labelled.

    Parameters
    ----------
    img : (H, W) or (H, W, 3) uint8
    cam : str
        Camera name, for the labels.
    ru, tu : (n, 2) pixel arrays or None
        Reconstruction and truth in this camera's image.
    view_width, aspect_range, tip_min_px, font
        As :func:`overlay_panels` (``font``: the labels' font).

    Returns
    -------
    (h, view_width + 8 + h, 3) uint8 RGB
    """
    rgb = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB) if img.ndim == 2 else img
    h, w = rgb.shape[:2]
    both = [np.asarray(a, float) for a in (ru, tu) if a is not None and len(a)]
    pts = np.concatenate(both) if both else np.zeros((0, 2))
    fin = pts[np.all(np.isfinite(pts), axis=1)] if len(pts) else pts
    if len(fin):
        ext = np.ptp(fin, axis=0) + 80.0
        aspect = float(np.clip(ext[0] / ext[1], *aspect_range))
    else:
        aspect = w / h
    vw, vh = view_width, int(round(view_width / aspect))
    view_box = _crop_box(pts, w, h, pad=40, aspect=vw / vh, min_w=w / 3)
    zs = vh  # the tip zoom is square, as tall as the view
    tips = np.array([a[-1] for a in both if np.all(np.isfinite(a[-1]))]) if both else np.zeros((0, 2))
    if len(tips):
        span = float(np.ptp(tips, axis=0).max()) if len(tips) > 1 else 0.0
        zoom_box = _crop_box(tips, w, h, pad=max(tip_min_px / 2, 0.25 * span), aspect=1.0, min_w=tip_min_px)
    else:
        zoom_box = _crop_box(pts, w, h, pad=20, aspect=1.0, min_w=tip_min_px)
    row = np.full((vh, vw + 8 + zs, 3), 255, np.uint8)
    row[:, :vw] = _panel(rgb, view_box, vw, vh, ru, tu, zoom=False)
    row[:, vw + 8:] = _panel(rgb, zoom_box, zs, zs, ru, tu, zoom=True)
    pil = Image.fromarray(row)
    d = ImageDraw.Draw(pil)
    zf = zs / (zoom_box[2] - zoom_box[0])
    vf = vw / (view_box[2] - view_box[0])
    for x, label in ((0, f"{cam} camera, x{vf:.2f}"), (vw + 8, f"{cam}: tip, x{zf:.1f}")):
        tb = d.textbbox((x + 6, 5), label, font=font)
        d.rectangle((tb[0] - 4, tb[1] - 3, tb[2] + 4, tb[3] + 3), fill=(255, 255, 255))
        d.text((x + 6, 5), label, fill=(0, 0, 0), font=font)
    return np.asarray(pil)


def _legend_strip(width: int, header: str, has_recon: bool, has_truth: bool) -> np.ndarray:
    """The strip on top of an overlay: ``header`` and the legend of the curves drawn (``width`` px wide, RGB)."""
    small = _font(14)
    head = Image.new("RGB", (width, 56), (255, 255, 255))
    d = ImageDraw.Draw(head)
    size = 16  # smaller where the header would run off the strip (a failed frame's errors, status and time)
    while size > 10 and d.textlength(header, font=_font(size)) > width - 12:
        size -= 1
    d.text((6, 4), header, fill=(0, 0, 0), font=_font(size))
    x = 6
    for rgbc, label, show in ((RECON_RGB, "reconstruction, reprojected through the calibration (o: tip)", has_recon),
                              (TRUTH_RGB, "ground truth as imaged (x: tip)", has_truth)):
        if not show:
            continue
        d.line((x, 40, x + 28, 40), fill=rgbc, width=4)
        d.text((x + 34, 31), label, fill=(0, 0, 0), font=small)
        x += 34 + d.textlength(label, font=small) + 24
    return np.asarray(head)


def overlay_panels(path, images: dict, recon_uv: dict, truth_uv: dict, header: str, footer: str = "",
                   view_width: int = 640, aspect_range=(4 / 3, 2.4), tip_min_px: float = 64.0, colours: int = 256) -> Path:
    """One PNG per frame: each camera's image with the reprojected reconstruction and truth.

    Each camera gets a row: the robot region (cropped around both curves, ``view_width``
    wide, its aspect following the robot's within ``aspect_range``) and a square zoom
    on the tip (at least ``tip_min_px`` image pixels wide, grown to hold both tips).
    Reconstruction blue (dots: its points in the zoom, circle: its tip), truth orange
    (cross: its tip), a legend on top, and ``footer`` (e.g. a failure reason) below.

    Parameters
    ----------
    images : dict camera -> (H, W) or (H, W, 3) uint8
    recon_uv, truth_uv : dict camera -> (n, 2) pixel arrays (or missing / None)
    header : str
        First line of the legend strip (frame, time, errors).
    colours : int
        Palette size of the PNG (the noisy camera images compress poorly in full RGB).
    """
    small = _font(14)
    rows = [_camera_row(img, cam, recon_uv.get(cam), truth_uv.get(cam), view_width, aspect_range, tip_min_px, small)
            for cam, img in images.items()]
    width = max((r.shape[1] for r in rows), default=800)
    has_truth = any(v is not None and len(v) for v in truth_uv.values())
    has_recon = any(v is not None and len(v) for v in recon_uv.values())
    parts = [_legend_strip(width, header, has_recon, has_truth)]
    for r in rows:
        if r.shape[1] < width:
            r = np.concatenate([r, np.full((r.shape[0], width - r.shape[1], 3), 255, np.uint8)], axis=1)
        parts += [r, np.full((8, width, 3), 255, np.uint8)]
    if footer:
        foot = Image.new("RGB", (width, 26), (255, 255, 255))
        ImageDraw.Draw(foot).text((6, 4), footer, fill=FAIL_RGB, font=small)
        parts.append(np.asarray(foot))
    out = np.concatenate(parts, axis=0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # a median-cut palette keeps the (noisy) camera images faithful at 2/3 of the RGB size;
    # fewer colours posterize the background without saving much
    Image.fromarray(out).quantize(colors=colours, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(path, compress_level=6)
    return path


# ----------------------------------------------------------------------------- run data
@dataclass
class RunData:
    """What a report is made from, read from a run directory."""

    out: Path
    summary: dict
    backbones: dict                      # frame -> (n, 3) world mm
    session_dir: Path | None = None
    session_meta: dict = field(default_factory=dict)
    rig: object = None                   # RigCalibration or None
    truth_keys: dict = field(default_factory=dict)  # frame -> truth npz path
    truth_notes: dict = field(default_factory=dict)  # frame -> why its truth could not be used

    @property
    def records(self) -> list:
        return self.summary.get("per_frame", [])

    def truth(self, frame: int, keys=("backbone_world_mm", "outer_radius_mm")) -> dict | None:
        """The wanted ground-truth arrays of a frame (only those are decompressed), checked as the session
        format says (:func:`rig.session_checks.check_truth`). A file that is unreadable or malformed is
        that frame's note in ``truth_notes`` (drawn without truth), never the end of the report."""
        path = self.truth_keys.get(frame)
        if path is None:
            return None
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in keys if k in z.files}
            return check_truth(arrays, path, {}, 0)
        except TruthError as exc:
            self.truth_notes[frame] = str(exc)
        except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
            self.truth_notes[frame] = f"{path}: unreadable ground truth ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})"
        return None


def load_run(out_dir) -> RunData:
    """Read a run directory: what its summary lists (:func:`rig.rundir.read_run`), and the session.

    Raises ``FileNotFoundError``/``ValueError`` with one line naming the file when the
    directory holds no run, or a file the summary lists is missing or another run's.
    """
    out = Path(out_dir)
    if not out.is_dir():
        raise FileNotFoundError(f"{out}: not a directory")
    summary, backbones = read_run(out)
    run = RunData(out=out, summary=summary, backbones=backbones)
    candidates = []
    if summary.get("session"):
        candidates.append(Path(summary["session"]))
    candidates.append(out / "session")
    for c in candidates:
        if (c / "session.json").exists():
            run.session_dir = c
            break
    if run.session_dir is not None:
        try:
            run.session_meta = json.loads((run.session_dir / "session.json").read_text())
        except (OSError, json.JSONDecodeError):
            run.session_meta = {}
        try:
            run.rig = load_rig_calibration(run.session_dir / "rig.json")
        except (OSError, ValueError, KeyError):
            run.rig = None
        tdir = run.session_dir / "truth"
        if tdir.is_dir():
            for p in tdir.glob("[0-9]*.npz"):
                run.truth_keys[int(p.stem)] = p
    return run


def select_detail_frames(records: list, limit: int = MAX_DETAIL_FRAMES) -> list:
    """Frames shown one by one: all of them up to ``limit``; beyond, failed, worst and evenly spaced."""
    frames = [r["frame"] for r in records]
    if len(frames) <= limit:
        return frames
    chosen = [r["frame"] for r in records if r["status"] != "ok"][: limit // 3]
    scored = sorted((r for r in records if r.get("mean_error_mm") is not None), key=lambda r: -r["mean_error_mm"])
    chosen += [r["frame"] for r in scored[: limit // 4]]
    chosen = list(dict.fromkeys(chosen))
    rest = [f for f in frames if f not in set(chosen)]
    k = limit - len(chosen)
    if k > 0 and rest:
        idx = np.unique(np.linspace(0, len(rest) - 1, k).round().astype(int))
        chosen += [rest[i] for i in idx]
    return sorted(set(chosen))


def _tube_radii(run: RunData) -> tuple:
    p = run.summary.get("params") or {}
    if "outer_tube_radius_mm" in p and "inner_tube_radius_mm" in p:
        return float(p["outer_tube_radius_mm"]), float(p["inner_tube_radius_mm"])
    tubes = (run.session_meta.get("robot") or {}).get("tubes") or []
    if len(tubes) >= 2:
        return tubes[0]["outer_diameter_mm"] / 2, tubes[-1]["outer_diameter_mm"] / 2
    if len(tubes) == 1:
        return tubes[0]["outer_diameter_mm"] / 2, tubes[0]["outer_diameter_mm"] / 2
    return 0.8, 0.5


# ----------------------------------------------------------------------------- HTML
# The page's layout is rig/bench/templates/report.html.j2; the functions below compute what it shows:
# every number already formatted, every row a dict. Text from a session (file names, notes, reasons)
# stays plain str: the template escapes it.
_DASH = "\u2013"  # a missing number (an en dash)


@functools.lru_cache(maxsize=1)
def _template():
    """The report page's jinja2 template, loaded once (from the installed package, so a wheel finds it too)."""
    env = Environment(loader=PackageLoader("rig.bench", "templates"),
                      # every template escapes: a note with markup in it shows as text, never runs
                      autoescape=select_autoescape(("html", "html.j2"), default=True),
                      undefined=StrictUndefined, trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True)
    return env.get_template("report.html.j2")


def _f(v, p=3, unit=""):
    """A number with ``p`` decimals and its unit; a dash when it is missing or not finite."""
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return _DASH
    return f"{v:.{p}f}{unit}"


def _px(v, mmpp):
    """`` (N px)``: a length in mm as pixels at the base (``mmpp`` mm per pixel); empty without either."""
    if v is None or not mmpp:
        return ""
    return f" ({v / mmpp:.1f} px)"


def _html_page(run: RunData, figs: dict, details: list, meshes: dict, notes: list, built_s: float) -> str:
    """The report page: summary, figures, frame table, failed frames and the frame-by-frame overlays.

    Parameters
    ----------
    run : RunData
        The run the page is about.
    figs : dict
        Figure key -> file name relative to the page; ``"overlay"`` maps frame -> overlay PNG.
    details : list of int
        Frames shown one by one (with their overlays).
    meshes : dict
        Frame -> {format: link} of the mesh files written (empty: none).
    notes : list of str
        Remarks shown under the summary (plain text, escaped by the template).
    built_s : float
        Time the report took to build, s.

    Returns
    -------
    str
        The HTML document.
    """
    s = run.summary
    scene = run.session_meta.get("scene_name") or ""
    return _template().render(
        title=f"ctr-bench report: {scene + ' — ' if scene else ''}method {s.get('method', '?')}",
        out=str(run.out), session=str(s.get("session", "")), source=run.session_meta.get("source") or "",
        built_at=time.strftime("%Y-%m-%d %H:%M:%S"), built_s=f"{built_s:.1f}",
        summary_rows=_summary_rows(s), params=json.dumps(s["params"], indent=2) if s.get("params") else "",
        notes=notes, figs=figs, mesh_frames=len(meshes), max_mesh_frames=MAX_MESH_FRAMES,
        frame_rows=_frame_rows(run.records, set(details), meshes), failed=_failed_groups(run.records, set(details)),
        detail_rows=_detail_rows(run.records, figs.get("overlay", {}), details), n_records=len(run.records))


def _summary_rows(s: dict) -> list:
    """The summary table's rows; figures the run did not measure are left out.

    Parameters
    ----------
    s : dict
        The run's ``summary.json``: errors in mm, times in ms, ``mm_per_px`` in mm per pixel at the base.

    Returns
    -------
    list of dict
        ``label``, and the value as ``strong`` (shown bold; may be empty) followed by ``text``.
    """
    def row(label, text, strong=""):
        return {"label": label, "strong": strong, "text": text}

    mmpp = s.get("mm_per_px")
    rows = [
        row("method", str(s.get("method"))),
        row("frames", f"{s.get('frames', 0)} ({s.get('failed_frames', 0)} failed, "
                      + (f"{s.get('suspect_frames', 0)} suspect by the self-check, " if s.get("suspect_frames") is not None else "")
                      + (f"{s['jump_frames']} with a temporal jump, " if s.get("jump_frames") else "")
                      + f"{s.get('scored_frames', 0)} ok frames scored against ground truth)"),
        row("pixel footprint at the base", _f(mmpp, 4, " mm")),
    ]
    if s.get("mean_error_mm") is not None:
        rows += [
            row("mean error", _px(s["mean_error_mm"], mmpp), strong=_f(s["mean_error_mm"], 3, " mm")),
            row("max error (worst frame's Hausdorff)", f"{_f(s.get('max_error_mm'), 3, ' mm')}{_px(s.get('max_error_mm'), mmpp)}"),
            row("tip error, median / max", f"{_f(s.get('tip_error_mm_median'), 3)} / {_f(s.get('tip_error_mm_max'), 3, ' mm')}"
                f"{_px(s.get('tip_error_mm_median'), mmpp)}"),
            row("length error, median", _f(s.get("length_error_mm_median"), 3, " mm")),
        ]
    if s.get("voxel_edge_mm_median") is not None:
        rows.append(row("voxel edge (largest of three), median / max", f"{_f(s['voxel_edge_mm_median'], 3)} / {_f(s.get('voxel_edge_mm_max'), 3, ' mm')}"))
    if s.get("ms_per_pair_median") is not None:
        fps = 1e3 / s["ms_per_pair_median"] if s["ms_per_pair_median"] else None
        rows.append(row("time per pair, median / p95", f" / {_f(s.get('ms_per_pair_p95'), 1, ' ms')}{f' ({fps:.1f} pairs/s)' if fps else ''}",
                        strong=_f(s["ms_per_pair_median"], 1)))
    return rows


def _frame_rows(records: list, shown: set, meshes: dict) -> list:
    """The per-frame table's rows: status, sizes and errors (mm), time (ms), links to the frame and its meshes.

    Parameters
    ----------
    records : list of dict
        The run's per-frame records; one row each.
    shown : set of int
        Frames shown one by one (their rows link to them).
    meshes : dict
        Frame -> {format: link} of the mesh files written.

    Returns
    -------
    list of dict
        Formatted cells; ``cls`` the row's class (its status unless ok), ``jump`` and ``note`` None when absent,
        ``meshes`` (format, link) pairs.
    """
    rows = []
    for r in records:
        fr, status = r["frame"], str(r["status"])
        if status == "suspect":
            status += f": {r.get('reason')}"
        m = meshes.get(fr, {})
        rows.append({
            "frame": fr, "cls": str(r["status"]) if r["status"] != "ok" else "", "status": status,
            "jump": str(r.get("jump_reason")) if r.get("jump_flag") else None,
            "note": str(r["note"]) if r.get("note") else None,
            "t": _f(r.get("t_s"), 2), "points": r.get("n_points") or _DASH, "length": _f(r.get("length_mm"), 1),
            "transition": _f(r.get("transition_s_mm"), 1), "tip": _f(r.get("tip_error_mm")), "mean": _f(r.get("mean_error_mm")),
            "max": _f(r.get("max_error_mm")), "length_err": _f(r.get("length_error_mm"), 2), "ms": _f(r.get("ms"), 1),
            "view": fr in shown, "meshes": [(fmt, m[fmt]) for fmt in ("ply", "obj", "glb", "both.glb") if fmt in m],
        })
    return rows


def _failed_groups(records: list, shown: set) -> dict:
    """The failed and suspect frames grouped by status and reason: failed first, then the largest groups.

    Parameters
    ----------
    records : list of dict
        The run's per-frame records.
    shown : set of int
        Frames shown one by one (their numbers link to them).

    Returns
    -------
    dict
        ``n_failed``, ``n_suspect`` (frame counts) and ``groups``: dicts of ``status``, ``reason`` and
        ``frames``, (frame, shown) pairs.
    """
    failed = [r for r in records if r["status"] != "ok"]
    groups = {}
    for r in failed:
        groups.setdefault((str(r["status"]), str(r.get("reason"))), []).append(r["frame"])
    n_suspect = sum(r["status"] == "suspect" for r in failed)
    order = sorted(groups.items(), key=lambda kv: (kv[0][0] != "failed", -len(kv[1]), kv[1][0]))
    return {"n_failed": len(failed) - n_suspect, "n_suspect": n_suspect,
            "groups": [{"status": st, "reason": why, "frames": [(f, f in shown) for f in frs]} for (st, why), frs in order]}


def _detail_rows(records: list, overlays: dict, details: list) -> list:
    """The frame-by-frame section: each detail frame's overlay picture, or why it failed when there is none.

    Parameters
    ----------
    records : list of dict
        The run's per-frame records.
    overlays : dict
        Frame -> overlay PNG relative to the page (empty when overlays were not drawn).
    details : list of int
        Frames to show (empty: no section).

    Returns
    -------
    list of dict
        ``frame``, ``overlay`` (link or None) and ``failure`` (status and reason of a frame not ok without
        an overlay, else empty).
    """
    by = {r["frame"]: r for r in records}
    rows = []
    for fr in details:
        r = by.get(fr, {})
        overlay = overlays.get(fr)
        failure = f"{r.get('status')}: {r.get('reason')}" if overlay is None and r.get("status") != "ok" else ""
        rows.append({"frame": fr, "overlay": overlay, "failure": failure})
    return rows


# ----------------------------------------------------------------------------- builder
def _frame_header(r: dict, mmpp) -> str:
    parts = [f"frame {r['frame']}", f"t = {r.get('t_s', 0):.2f} s"]
    if r["status"] != "ok":
        parts.append(str(r["status"]).upper())
    for key, lab in (("tip_error_mm", "tip error"), ("mean_error_mm", "mean error"), ("max_error_mm", "max error")):
        v = r.get(key)
        if v is not None:
            parts.append(f"{lab} {v:.2f} mm" + (f" ({v / mmpp:.1f} px)" if mmpp else ""))
    if r.get("ms") is not None:
        parts.append(f"{r['ms']:.0f} ms")
    return "   ·   ".join(parts)


def frame_overlay(run: RunData, r: dict, path: Path) -> Path | None:
    """The PNG of frame record ``r`` of ``run`` (:func:`overlay_panels`: each camera's image, the backbone and the
    truth reprojected), written to ``path``; None where none of the frame's images can be read."""
    fr = r["frame"]
    cams = list(run.session_meta.get("cameras") or (run.rig.names if run.rig else []))
    images = {}
    for cam in cams:
        p = run.session_dir / "frames" / cam / f"{fr:06d}.png"
        try:
            images[cam] = read_image(p)
        except (OSError, ValueError):
            continue
    if not images:
        return None
    truth = run.truth(fr, keys=["backbone_world_mm"] + [f"centerline_px_{c}" for c in images] + [f"T_cam_world_{c}" for c in images])
    recon_uv, truth_uv = {}, {}
    pts = run.backbones.get(fr)
    for cam in images:
        cam_model = run.rig[cam] if run.rig is not None and cam in run.rig.cameras else None
        if pts is not None and len(pts) and cam_model is not None:
            recon_uv[cam] = cam_model.project(pts)[0]
        if truth is not None:
            if f"centerline_px_{cam}" in truth:
                truth_uv[cam] = np.asarray(truth[f"centerline_px_{cam}"], float)
            elif "backbone_world_mm" in truth and cam_model is not None:
                c = cam_model.with_pose(truth[f"T_cam_world_{cam}"]) if f"T_cam_world_{cam}" in truth else cam_model
                truth_uv[cam] = c.project(truth["backbone_world_mm"])[0]
    footer = f"{r['status']}: {r.get('reason')}" if r["status"] != "ok" else ""
    return overlay_panels(path, images, recon_uv, truth_uv, _frame_header(r, run.summary.get("mm_per_px")), footer)


def _fresh_dir(path: Path) -> Path:
    """Empty ``path`` (a leftover of an interrupted build is removed) and create it with its ``frames/``.

    Parameters
    ----------
    path : Path
        The temporary report directory.

    Returns
    -------
    Path
        ``path``.
    """
    if path.exists():
        shutil.rmtree(path)
    (path / "frames").mkdir(parents=True)
    return path


def _truth_backbones(run: RunData) -> dict:
    """Frame -> ground truth (``backbone_world_mm``, mm, and ``outer_radius_mm``) of the frames that have a true backbone.

    Parameters
    ----------
    run : RunData
        The run; frames without truth (or without a session) are left out.

    Returns
    -------
    dict
    """
    truth_bb = {}
    for r in run.records:
        t = run.truth(r["frame"], keys=("backbone_world_mm", "outer_radius_mm"))
        if t is not None and "backbone_world_mm" in t:
            truth_bb[r["frame"]] = t
    return truth_bb


def _error_figures(tmp: Path, recs: list, ok: list, bbs: list, truths: list, mmpp) -> dict:
    """Draw the error figures: error along the arc (frames with a true backbone) and errors per frame.

    Parameters
    ----------
    tmp : Path
        Directory the PNGs go to.
    recs : list of dict
        Every frame's record (errors in mm).
    ok, bbs, truths : list
        The reconstructed frames' records, backbones (N x 3, mm) and true backbones (mm; None without truth).
    mmpp : float or None
        Pixel footprint at the base, mm per pixel (the right axes in pixels).

    Returns
    -------
    dict
        Figure key -> PNG file name.
    """
    figs = {}
    curves, ctimes = [], []
    for r, b, tr in zip(ok, bbs, truths):
        if tr is not None and len(b):
            curves.append(closest_arc_length(b, tr))
            ctimes.append(r.get("t_s") or 0.0)
    if curves:
        figs["error_along_arc"] = fig_error_along_arc(tmp / "error_along_arc.png", curves, ctimes, mmpp).name
    figs["errors_per_frame"] = fig_errors_per_frame(
        tmp / "errors_per_frame.png", [r["frame"] for r in recs], [r.get("mean_error_mm") for r in recs],
        [r.get("max_error_mm") for r in recs], [r.get("tip_error_mm") for r in recs],
        [r["frame"] for r in recs if r["status"] == "failed"], mmpp).name
    return figs


def _timing_figure(tmp: Path, recs: list) -> str:
    """Draw the timing figure: time per pair of the ok frames and, when recorded, per stage (ms).

    Parameters
    ----------
    tmp : Path
        Directory the PNG goes to.
    recs : list of dict
        Every frame's record (``ms``, ``timings_ms``).

    Returns
    -------
    str
        The PNG's file name.
    """
    ms = [r["ms"] for r in recs if r["status"] == "ok" and r.get("ms") is not None]
    stage = {}
    for r in recs:
        for k, v in (r.get("timings_ms") or {}).items():
            if v is not None:
                stage.setdefault(k, []).append(v)
    return fig_timing(tmp / "timing.png", ms, stage or None).name


def _preview_tube(b: np.ndarray, trans, outer_r: float, inner_r: float):
    """A light tube mesh for the pictures: 1 mm rings, 10 sides (full meshes would make matplotlib slow).

    Parameters
    ----------
    b : ndarray (N, 3)
        Backbone, mm.
    trans : float or None
        Arc length of the outer-to-inner tube transition, mm.
    outer_r, inner_r : float
        Tube radii, mm.
    """
    s = arc_length(b)
    n = max(2, int(np.ceil(s[-1] / 1.0)) + 1)
    sn = np.linspace(0, s[-1], n)
    p = np.stack([np.interp(sn, s, b[:, k]) for k in range(3)], axis=1)
    return tube_mesh(p, radii_along(sn, trans, outer_r, inner_r), sides=10)


def _tube_figures(tmp: Path, ok: list, rec_mesh: dict, truth_bb: dict, outer_r: float, inner_r: float, notes: list) -> dict:
    """Draw the tube pictures: every frame's tube over time, and up to six frames against their true tubes.

    Parameters
    ----------
    tmp : Path
        Directory the PNGs go to.
    ok : list of dict
        The reconstructed frames' records.
    rec_mesh : dict
        Frame -> (backbone, mm; transition arc length, mm) of the frames with a tube.
    truth_bb : dict
        Frame -> ground truth (see :func:`_truth_backbones`).
    outer_r, inner_r : float
        Tube radii, mm.
    notes : list of str
        Gets a note when the pictures cannot be drawn.

    Returns
    -------
    dict
        Figure key -> PNG file name (what was drawn before a failure).
    """
    figs = {}
    order = [r["frame"] for r in ok if r["frame"] in rec_mesh]
    try:
        figs["tubes_over_time"] = fig_tubes(tmp / "tubes_over_time.png", [], over_time=(
            [_preview_tube(*rec_mesh[f], outer_r, inner_r) for f in order],
            [r.get("t_s") or 0.0 for r in ok if r["frame"] in rec_mesh])).name
        pick = [order[i] for i in np.unique(np.linspace(0, len(order) - 1, min(6, len(order))).round().astype(int))]
        panels, titles = [], []
        for f in pick:
            t = truth_bb.get(f)
            panels.append((recon_tube(*rec_mesh[f], outer_r, inner_r, sides=12),
                           truth_tube(t["backbone_world_mm"], t.get("outer_radius_mm"), step_mm=1.0, sides=12) if t is not None else None))
            titles.append(f"frame {f}")
        figs["tubes"] = fig_tubes(tmp / "tubes.png", panels, titles).name
    except ValueError as exc:
        notes.append(f"tube pictures skipped: {exc}")
    return figs


def _write_meshes(run: RunData, rec_mesh: dict, outer_r: float, inner_r: float, notes: list) -> dict:
    """Write each frame's tube meshes (PLY, OBJ, GLB, world mm) into ``OUT/meshes/``.

    Parameters
    ----------
    run : RunData
        The run (its truth goes into the ``_both.glb`` files).
    rec_mesh : dict
        Frame -> (backbone, mm; transition arc length, mm).
    outer_r, inner_r : float
        Tube radii, mm.
    notes : list of str
        Gets a note per frame whose mesh could not be made.

    Returns
    -------
    dict
        Frame -> {format: link relative to the report page}.
    """
    mdir = run.out / "meshes"
    mesh_links = {}
    for f, (b, trans) in rec_mesh.items():
        tr = run.truth(f, keys=("backbone_world_mm", "outer_radius_mm"))
        try:
            paths = write_frame_meshes(mdir, f, b, trans, tr, outer_r, inner_r)
        except ValueError as exc:
            notes.append(f"frame {f}: no mesh ({exc})")
            continue
        d = {}
        for p in paths:
            key = "both.glb" if p.name.endswith("_both.glb") else p.suffix[1:]
            d[key] = f"../meshes/{p.name}"
        mesh_links[f] = d
    return mesh_links


def _overlay_figures(run: RunData, details: list, tmp: Path) -> dict:
    """Draw the camera overlays of the detail frames into ``tmp/frames/``.

    Parameters
    ----------
    run : RunData
        The run (with its session's images).
    details : list of int
        Frames to draw.
    tmp : Path
        The temporary report directory.

    Returns
    -------
    dict
        Frame -> overlay PNG relative to the page (frames without images are left out).
    """
    overlays = {}
    by = {r["frame"]: r for r in run.records}
    for f in details:
        p = frame_overlay(run, by[f], tmp / "frames" / f"{f:06d}.png")
        if p is not None:
            overlays[f] = f"frames/{p.name}"
    return overlays


def build_report(out_dir, meshes: bool | None = None, max_detail_frames: int = MAX_DETAIL_FRAMES, overlays: bool = True, log=None) -> Path:
    """Build ``OUT/report/index.html`` (and, per the mesh rule, ``OUT/meshes/``) for a run directory.

    Parameters
    ----------
    out_dir : path
        A ``run`` / ``reconstruct`` output directory (with ``summary.json``).
    meshes : bool or None
        Write tube meshes (PLY, OBJ, GLB) of every reconstructed frame: True always,
        False never, None (default) when the run has at most :data:`MAX_MESH_FRAMES`.
    max_detail_frames : int
        Frames with their own overlay picture at most (a selection beyond).
    overlays : bool
        Draw the camera overlays (needs the session's images).
    log : callable(str), optional
        Progress lines.

    Returns
    -------
    Path of ``index.html``.
    """
    t_start = time.perf_counter()
    run = load_run(out_dir)
    out = run.out
    say = log or (lambda msg: None)
    # built aside and renamed at the end: an interrupted build never leaves half a report
    tmp = _fresh_dir(out / ".report-tmp")
    figs, notes = {}, []
    recs = run.records
    ok = [r for r in recs if r["status"] == "ok" and r["frame"] in run.backbones]
    times = np.array([r.get("t_s") or 0.0 for r in ok], float)
    bbs = [run.backbones[r["frame"]] for r in ok]
    truth_bb = _truth_backbones(run)
    truths = [truth_bb[r["frame"]]["backbone_world_mm"] if r["frame"] in truth_bb else None for r in ok]
    base = run.rig.base_point_world_mm if run.rig is not None else None
    mmpp = run.summary.get("mm_per_px")
    if run.session_dir is None:
        notes.append("The session directory was not found: no camera overlays and no ground truth in this report.")

    say("report: figures")
    if bbs:
        drawn_truths = truths if any(t is not None for t in truths) else None
        figs["backbones_3d"] = fig_backbones_3d(tmp / "backbones_3d.png", bbs, times, drawn_truths, base).name
        figs["projections"] = fig_projections(tmp / "projections.png", bbs, times, drawn_truths, base).name
    if any(r.get("mean_error_mm") is not None for r in recs) or truth_bb:
        figs.update(_error_figures(tmp, recs, ok, bbs, truths, mmpp))
    figs["timing"] = _timing_figure(tmp, recs)

    outer_r, inner_r = _tube_radii(run)
    # a tube needs two backbone points at least
    rec_mesh = {r["frame"]: (run.backbones[r["frame"]], r.get("transition_s_mm"))
                for r in ok if len(run.backbones[r["frame"]]) >= 2}
    if rec_mesh:
        say("report: tubes")
        figs.update(_tube_figures(tmp, ok, rec_mesh, truth_bb, outer_r, inner_r, notes))
    mesh_links = {}
    if rec_mesh and (meshes or (meshes is None and len(recs) <= MAX_MESH_FRAMES)):
        say(f"report: meshes of {len(rec_mesh)} frames")
        mesh_links = _write_meshes(run, rec_mesh, outer_r, inner_r, notes)

    details = select_detail_frames(recs, max_detail_frames)
    if overlays and run.session_dir is not None and details:
        say(f"report: overlays of {len(details)} frames")
        figs["overlay"] = _overlay_figures(run, details, tmp)

    # Frames whose truth file could not be used are drawn without truth: said here, and by the caller's log.
    for frame, why in sorted(run.truth_notes.items()):
        notes.append(f"Frame {frame} is drawn without ground truth: {why}")
        say(f"report: frame {frame} without ground truth: {why}")
    page = _html_page(run, figs, details, mesh_links, notes, time.perf_counter() - t_start)
    (tmp / "index.html").write_text(page, encoding="utf-8")
    final = out / "report"
    if final.exists():
        shutil.rmtree(final)
    tmp.replace(final)
    return final / "index.html"


def report_or_warn(out_dir, **kw) -> Path | None:
    """Build the report at the end of ``run`` / ``reconstruct``; a failure is one warning line, never a lost run.

    Set ``CTR_BENCH_DEBUG=1`` to see the traceback instead.
    """
    try:
        index = build_report(out_dir, **kw)
    except Exception as exc:  # noqa: BLE001 - the reconstruction is on disk; the report can be rebuilt
        if os.environ.get("CTR_BENCH_DEBUG"):
            raise
        msg = " ".join(str(exc).split()) or type(exc).__name__
        print(f"report: not built ({type(exc).__name__}: {msg}); try: ctr-bench report {out_dir}", file=sys.stderr)
        return None
    size = sum(p.stat().st_size for p in index.parent.rglob("*") if p.is_file())
    mdir = Path(out_dir) / "meshes"
    msize = sum(p.stat().st_size for p in mdir.glob("*") if p.is_file()) if mdir.is_dir() else 0
    extra = f", meshes in {mdir} ({msize / 1e6:.1f} MB)" if msize else ""
    print(f"report: {index} ({size / 1e6:.1f} MB){extra}")
    return index
