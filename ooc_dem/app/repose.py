"""Angle of repose of a heap of spheres or discs: the measurement and its figure
(docs/reference/repose3d.md; the ``repose3d`` and ``repose2d`` built-ins, ``[repose]`` keys).

Method (``measure``), on the final positions and radii only:

1. The heap's height H is the highest sphere top max(y + r) above the floor y = 0; its
   axis is the mean (x, z) of the spheres whose tops are above H / 2 (the heap's core,
   which spheres that rolled away along the floor do not pull aside).
2. Around the axis the plane is cut into ``sectors`` equal azimuthal sectors and, in
   each, into radial bins of ``bin_width``; each sector's bin is cut along its arc into
   cells about ``bin_width`` long (at least one), so that every cell covers about the
   same area, bin_width^2, at any radius. The surface is the highest sphere top of each
   cell (spheres inside the heap never count: the surface is what a laser scan of a
   real heap sees), and a sector's profile at that bin is the mean of its cells' highest
   tops, at the mean distance from the axis of those highest spheres. Equal cells make
   the roughness bias of a maximum (more spheres in a cell, a higher maximum) the same
   at every radius, so it shifts the profile without tilting it.
3. Per sector, the flank is the bins beyond the sector's highest bin whose profile lies
   between ``fit_low`` H and ``fit_high`` H (this leaves out the rounded apex and the
   toe, where the heap runs out into a layer one sphere thick); a least-squares line
   h = a - rho tan(theta) through them gives the sector's angle theta. (Placing each
   point at its bin's centre instead would bias the angle low: a flank bin's highest
   sphere sits near the bin's inner edge, nearer the fewer spheres the bin holds, and
   bins near the axis hold fewer.)
4. The angle of repose is the mean of the sectors' angles; their standard deviation and
   standard error are reported with it (a sector needs at least MIN_FLANK_BINS bins).

In 2D (positions of two columns: a heap of discs, the ``repose2d`` built-in) the same
steps run with the heap's two flanks, left and right of its axis (the mean x of the
core), as the sectors: a flank's profile is the highest disc top of each bin of
``bin_width`` along x (one cell per bin: every bin covers the same length), and the
angle is the mean of the two flanks' angles (both must have a flank to fit).

``heap_outputs`` turns a run's final state into ``summary.json``'s ``repose`` entry and
``figures/repose.png`` (the profile, the fitted flank lines and the angle).
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import OocDemError
from ..storage.atomic import write_replacing
from ..physics.layout import AX_X, AX_Y, AX_Z

if TYPE_CHECKING:
    from ..model.scenario import Scenario

REPOSE_FIGURE = "repose.png"
MIN_FLANK_BINS = 3  # bins a sector's flank needs for a line fit
MIN_SECTORS_FRACTION = 0.5  # fitted sectors needed (of all) for an angle


class ReposeError(OocDemError, ValueError):
    """The heap has no measurable flank (message is one line)."""


def flanks(dim: int, sectors: int | None) -> int:
    """Profiles a heap of ``dim`` is measured in: ``sectors`` (8 unless given) in 3D; in 2D
    its two flanks, left and right of the axis."""
    if dim == 2:
        if sectors not in (None, 2):
            raise ReposeError(f"sectors = {sectors!r}: a 2D heap has two flanks (sectors = 2)")
        return 2
    return 8 if sectors is None else sectors


def _check(
    pos: ArrayLike, r: ArrayLike, sectors: int | None, bin_width: float, fit_low: float, fit_high: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    pos = np.asarray(pos, np.float64)
    r = np.asarray(r, np.float64)
    if pos.ndim != 2 or pos.shape[1] not in (2, 3) or r.shape != (len(pos),):
        raise ReposeError(f"positions must be (N, 2) or (N, 3) and radii (N,), got {pos.shape} and {r.shape}")
    if len(pos) == 0:
        raise ReposeError("no particles")
    if not (np.isfinite(pos).all() and np.isfinite(r).all()):
        raise ReposeError("non-finite positions or radii")
    if not (sectors is None or (isinstance(sectors, (int, np.integer)) and sectors >= 1)):
        raise ReposeError(f"sectors = {sectors!r}: must be an integer >= 1")
    n_sectors = flanks(pos.shape[1], sectors)
    if not bin_width > 0:
        raise ReposeError(f"bin_width = {bin_width!r}: must be > 0")
    if not 0.0 <= fit_low < fit_high <= 1.0:
        raise ReposeError(f"fit_low = {fit_low!r}, fit_high = {fit_high!r}: need 0 <= fit_low < fit_high <= 1")
    return pos, r, n_sectors


def surface_profiles(
    pos: NDArray[np.float64], r: NDArray[np.float64], sectors: int, bin_width: float
) -> tuple[float, tuple[float, ...], NDArray[np.float64], NDArray[np.float64]]:
    """(H, axis ((x, z) in 3D, (x,) in 2D), profile rho (sectors, K), profile height
    (sectors, K)) (module doc, step 2); NaN where a sector's bin is empty. In 2D (pos of
    two columns) the sectors are the two flanks, left (0) and right (1) of the axis, and a
    bin is one cell: every bin covers the same length at any distance."""
    top = pos[:, AX_Y] + r
    height = float(top.max())
    core = top > 0.5 * height
    k_axes = (AX_X, AX_Z) if pos.shape[1] == 3 else (AX_X,)
    centre = tuple(float(pos[core, a].mean()) for a in k_axes)
    dx = pos[:, AX_X] - centre[0]
    if len(centre) == 2:
        dz = pos[:, AX_Z] - centre[1]
        rho = np.hypot(dx, dz)
        frac = (np.arctan2(dz, dx) + math.pi) / (2 * math.pi) * sectors  # [0, sectors]
    else:
        rho = np.abs(dx)
        frac = (dx >= 0.0).astype(np.float64)  # the flank: 0 left, 1 right
    sec = np.minimum(frac, sectors - 1e-9).astype(np.int64)
    k = (rho / bin_width).astype(np.int64)
    nbins = int(k.max()) + 1
    if len(centre) == 2:
        # each sector's ring bin in cells about bin_width along the arc (at least one), so
        # that every cell covers about the same area at any radius
        arc = (np.arange(nbins) + 0.5) * bin_width * 2 * math.pi / sectors
        n_cells = np.maximum(1, np.round(arc / bin_width)).astype(np.int64)
    else:
        n_cells = np.ones(nbins, np.int64)
    sub = np.minimum(((frac - sec) * n_cells[k]).astype(np.int64), n_cells[k] - 1)
    ring = sec * nbins + k
    cell = ring * int(n_cells.max()) + sub
    # the highest particle of each cell: sort by (cell, top), take each cell's last
    order = np.lexsort((top, cell))
    last = np.r_[cell[order][1:] != cell[order][:-1], True]
    best = order[last]
    n = np.bincount(ring[best], minlength=sectors * nbins).astype(np.float64)
    with np.errstate(invalid="ignore"):
        prof_h = np.bincount(ring[best], top[best], sectors * nbins) / n
        prof_r = np.bincount(ring[best], rho[best], sectors * nbins) / n
    return height, centre, prof_r.reshape(sectors, nbins), prof_h.reshape(sectors, nbins)


def fit_flank(rho: NDArray[np.float64], h: NDArray[np.float64], lo: float, hi: float) -> dict[str, Any] | None:
    """Least-squares line through one sector's flank (module doc, step 3): dict of the
    fit, or None when fewer than MIN_FLANK_BINS bins qualify."""
    ok = np.isfinite(h)
    if not ok.any():
        return None
    peak = int(np.nanargmax(h))
    sel = ok & (np.arange(len(h)) > peak) & (h >= lo) & (h <= hi)
    n = int(sel.sum())
    if n < MIN_FLANK_BINS:
        return None
    x, y = rho[sel], h[sel]
    slope, intercept = np.polyfit(x, y, 1)
    resid = y - (slope * x + intercept)
    ss = float(np.sum((y - y.mean()) ** 2))
    return {
        "angle_deg": math.degrees(math.atan(-slope)),
        "slope": float(slope),
        "intercept_m": float(intercept),
        "bins": n,
        "rho_from_m": float(x.min()),
        "rho_to_m": float(x.max()),
        "r_squared": float(1.0 - np.sum(resid**2) / ss) if ss > 0 else 1.0,
    }


def measure(
    pos: ArrayLike,
    r: ArrayLike,
    sectors: int | None = None,
    bin_width: float = 0.005,
    fit_low: float = 0.2,
    fit_high: float = 0.8,
) -> dict[str, Any]:
    """The heap's angle of repose (module doc) as a JSON-ready dict; ReposeError when fewer
    than half the sectors have a flank to fit (in 2D: when either flank has none).
    ``sectors``: 8 unless given in 3D; 2 (the flanks) in 2D."""
    pos, r, sectors = _check(pos, r, sectors, bin_width, fit_low, fit_high)
    dim = pos.shape[1]
    height, axis, prof_r, prof = surface_profiles(pos, r, sectors, bin_width)
    lo, hi = fit_low * height, fit_high * height
    fits = [fit_flank(prof_r[s], prof[s], lo, hi) for s in range(sectors)]
    angles = np.array([f["angle_deg"] for f in fits if f is not None])
    # a 2D heap's angle is the mean of both flanks: one alone is no heap's angle
    need = sectors if dim == 2 else max(1, math.ceil(MIN_SECTORS_FRACTION * sectors))
    if len(angles) < need:
        what = "flanks have" if dim == 2 else "sectors have a flank of"
        bins = "bins" if dim == 2 else "radial bins"
        raise ReposeError(
            f"only {len(angles)} of {sectors} {what} >= {MIN_FLANK_BINS} {bins} between {fit_low:g} and {fit_high:g} of the heap height "
            f"{height:.4g} m (heap too flat or bins too wide)"
        )
    std = float(angles.std(ddof=1)) if len(angles) > 1 else 0.0
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a bin empty in every sector: NaN
        mean_prof = np.nanmean(prof, axis=0)
    if dim == 3:
        method = (
            f"surface profile in each of {sectors} azimuthal sectors around the heap's axis: per "
            f"radial bin of {bin_width:g} m the mean of the highest sphere tops of cells about "
            f"{bin_width:g} m x {bin_width:g} m; least-squares line over the flank between "
            f"{fit_low:g} and {fit_high:g} of the heap height; mean of the sectors' angles "
            f"(docs/reference/repose3d.md)"
        )
    else:
        method = (
            f"surface profile of each flank, left and right of the heap's axis: per bin of "
            f"{bin_width:g} m along x the highest disc top; least-squares line over the flank "
            f"between {fit_low:g} and {fit_high:g} of the heap height; mean of the two flanks' "
            f"angles (docs/reference/repose3d.md)"
        )
    return {
        "angle_deg": float(angles.mean()),
        "angle_std_deg": std,
        "angle_sem_deg": std / math.sqrt(len(angles)),
        "method": method,
        "dim": dim,
        "heap_height_m": height,
        "axis_m": list(axis),
        "fit_low": fit_low,
        "fit_high": fit_high,
        "bin_width_m": bin_width,
        "sectors": sectors,
        "sectors_fitted": int(len(angles)),
        "sector_fits": fits,
        "profile_bin_centres_m": ((np.arange(prof.shape[1]) + 0.5) * bin_width).tolist(),
        "profile_mean_m": [None if not np.isfinite(v) else float(v) for v in mean_prof],
    }


def angle_line(entry: Any) -> str | None:
    """One line of a run's angle of repose (summary.json's ``repose``), None without one."""
    if not isinstance(entry, dict) or not isinstance(entry.get("angle_deg"), (int, float)):
        return None
    n = entry.get("sectors_fitted", entry.get("sectors", "?"))
    parts = "flanks" if entry.get("dim") == 2 else "sectors"
    sd = entry.get("angle_std_deg")
    spread = f", sd {sd:.1f} deg" if isinstance(sd, (int, float)) else ""
    return f"angle of repose {entry['angle_deg']:.1f} deg ({n} {parts}{spread})"


def heap_outputs(
    out: str | os.PathLike[str],
    sc: Scenario,
    pos: NDArray[np.float64],
    r: NDArray[np.float64],
    vel: NDArray[np.float64],
    figures: bool = True,
) -> dict[str, Any]:
    """summary.json's ``repose`` entry of a finished repose run, and figures/repose.png.

    Never raises for the heap's shape: an unmeasurable heap gives ``angle_deg`` null and
    the reason, so that the run's other outputs are still written."""
    rp = sc.repose
    d_mean = float(2.0 * np.mean(r))
    speed = np.sqrt(np.einsum("ij,ij->i", vel, vel))
    entry: dict[str, Any] = {
        "unit": "deg",
        "friction": sc.contact.soil_soil.friction,
        "rolling_friction": sc.contact.soil_soil.rolling_friction,
        "column_radius_m": rp.column_radius,
        ("n_spheres" if sc.dim == 3 else "n_discs"): int(len(r)),
        "mean_diameter_m": d_mean,
        "mean_speed_m_s": float(speed.mean()),
        "max_speed_m_s": float(speed.max()),
    }
    m: dict[str, Any] | None
    try:
        sectors = rp.sectors if sc.dim == 3 else None  # 2D: the two flanks
        m = measure(pos, r, sectors, rp.bin_width, rp.fit_low, rp.fit_high)
    except ReposeError as e:
        entry.update(angle_deg=None, note=str(e))
        m = None
    else:
        entry.update(m)
        entry["heap_height_diameters"] = m["heap_height_m"] / d_mean
    if figures:
        fig_dir = Path(out) / "figures"
        fig_dir.mkdir(parents=True, exist_ok=True)
        repose_figure(pos, r, m, entry, fig_dir / REPOSE_FIGURE)
    return entry


def _angle_box(ax: Any, m: dict[str, Any] | None, entry: dict[str, Any], fits: str) -> None:
    """The figure's box: the angle, its spread, which fits made it (``fits``) and the heap's
    height; or why there is no angle."""
    if m is None:
        ax.text(
            0.5, 0.9, f"no angle: {entry.get('note', '')}", transform=ax.transAxes, ha="center", fontsize=8, wrap=True
        )
        return
    ax.text(
        0.98,
        0.95,
        f"angle of repose {m['angle_deg']:.1f}° ± {m['angle_std_deg']:.1f}° (sd)\n{fits}\n"
        f"H = {m['heap_height_m'] * 1e3:.1f} mm = {entry['heap_height_diameters']:.1f} d",
        transform=ax.transAxes,
        ha="right",
        va="top",
        fontsize=10,
        bbox={"fc": "w", "ec": "0.6"},
    )


def repose_figure(
    pos: NDArray[np.float64], r: NDArray[np.float64], m: dict[str, Any] | None, entry: dict[str, Any], path: Path
) -> Path:
    """Side view (every sphere at its distance from the heap's axis; the per-sector
    surface profiles; each sector's fitted flank line; the fit band) and top view; in 2D
    the heap in its plane (``repose_figure_2d``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if pos.shape[1] == 2:
        return repose_figure_2d(pos, r, m, entry, path)
    top = pos[:, AX_Y] + r
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 5), gridspec_kw={"width_ratios": [1.6, 1]})
    if m is not None:
        cx, cz = m["axis_m"]
    else:
        cx, cz = float(pos[:, AX_X].mean()), float(pos[:, AX_Z].mean())
    rho = np.hypot(pos[:, AX_X] - cx, pos[:, AX_Z] - cz)
    ax.scatter(rho * 1e3, pos[:, AX_Y] * 1e3, s=2, c="0.75", lw=0, label="spheres (centres)")
    if m is not None:
        H = m["heap_height_m"]
        _, _, rb, prof = surface_profiles(pos, r, m["sectors"], m["bin_width_m"])
        rb = np.where(np.isfinite(prof), rb, np.nan)
        cmap = plt.get_cmap("viridis")
        for s, fit in enumerate(m["sector_fits"]):
            col = cmap(s / max(1, m["sectors"] - 1))
            ok = np.isfinite(prof[s])
            ax.plot(rb[s][ok] * 1e3, prof[s][ok] * 1e3, "-", color=col, lw=0.8, alpha=0.6)
            if fit is not None:
                xs = np.array([fit["rho_from_m"], fit["rho_to_m"]])
                ax.plot(xs * 1e3, (fit["intercept_m"] + fit["slope"] * xs) * 1e3, "-", color=col, lw=2.2)
        for f in (m["fit_low"], m["fit_high"]):
            ax.axhline(f * H * 1e3, color="k", ls=":", lw=0.8)
    fits = (
        ""
        if m is None
        else f"{m['sectors_fitted']} of {m['sectors']} sectors, flank {m['fit_low']:g}–{m['fit_high']:g} H"
    )
    _angle_box(ax, m, entry, fits)
    ax.set_xlabel("distance from the heap's axis ρ [mm]")
    ax.set_ylabel("height y [mm]")
    ax.set_title(
        f"heap profile: surface per sector (thin), flank fits (thick); "
        f"μ = {entry['friction']:g}, μr = {entry['rolling_friction']:g}",
        fontsize=10,
    )
    # true proportions (the angle as seen), out to where 99.5 % of the spheres lie
    ax.set_xlim(0, 1.05e3 * float(np.quantile(rho, 0.995)))
    ax.set_ylim(0, 1.3e3 * float(top.max()))
    ax.set_aspect("equal", adjustable="box")
    order = np.argsort(top)
    sc_ = ax2.scatter(
        (pos[order, AX_X] - cx) * 1e3, (pos[order, AX_Z] - cz) * 1e3, s=3, c=top[order] * 1e3, cmap="terrain", lw=0
    )
    if m is not None:
        reach = float(np.nanmax(rho)) * 1e3
        for s in range(m["sectors"]):
            a = -math.pi + 2 * math.pi * s / m["sectors"]
            ax2.plot([0, reach * math.cos(a)], [0, reach * math.sin(a)], color="k", lw=0.5, alpha=0.5)
    ax2.set_aspect("equal")
    ax2.set_xlabel("x − axis [mm]")
    ax2.set_ylabel("z − axis [mm]")
    ax2.set_title("top view: sphere tops by height; the sectors", fontsize=10)
    fig.colorbar(sc_, ax=ax2, label="top height [mm]", shrink=0.8)
    fig.tight_layout()
    write_replacing(path, lambda tmp: fig.savefig(tmp, dpi=120, format="png"))
    plt.close(fig)
    return path


def repose_figure_2d(
    pos: NDArray[np.float64], r: NDArray[np.float64], m: dict[str, Any] | None, entry: dict[str, Any], path: Path
) -> Path:
    """The 2D heap in its plane at true proportions: the discs' centres, each flank's
    surface profile and fitted line, the fit band and the angle."""
    import matplotlib.pyplot as plt

    top = pos[:, AX_Y] + r
    fig, ax = plt.subplots(figsize=(12, 4.5))
    ax.scatter(pos[:, AX_X] * 1e3, pos[:, AX_Y] * 1e3, s=2, c="0.75", lw=0, label="discs (centres)")
    cx = float(m["axis_m"][0]) if m is not None else float(pos[:, AX_X].mean())
    if m is not None:
        H = m["heap_height_m"]
        _, _, rb, prof = surface_profiles(pos, r, m["sectors"], m["bin_width_m"])
        for side, fit, col in zip((-1.0, 1.0), m["sector_fits"], ("tab:blue", "tab:orange")):
            s = 0 if side < 0 else 1
            ok = np.isfinite(prof[s])
            ax.plot((cx + side * rb[s][ok]) * 1e3, prof[s][ok] * 1e3, "-", color=col, lw=0.8, alpha=0.7)
            if fit is not None:
                xs = np.array([fit["rho_from_m"], fit["rho_to_m"]])
                ax.plot((cx + side * xs) * 1e3, (fit["intercept_m"] + fit["slope"] * xs) * 1e3, "-", color=col, lw=2.2)
        for f in (m["fit_low"], m["fit_high"]):
            ax.axhline(f * H * 1e3, color="k", ls=":", lw=0.8)
    fits = "" if m is None else f"{m['sectors_fitted']} flanks, {m['fit_low']:g}–{m['fit_high']:g} H"
    _angle_box(ax, m, entry, fits)
    ax.axvline(cx * 1e3, color="0.5", lw=0.5)
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("height y [mm]")
    ax.set_title(
        f"2D heap: surface per flank (thin), flank fits (thick); "
        f"μ = {entry['friction']:g}, μr = {entry['rolling_friction']:g}",
        fontsize=10,
    )
    x0, x1 = np.quantile(pos[:, AX_X], [0.0025, 0.9975])
    pad = 0.05 * float(x1 - x0)
    ax.set_xlim((float(x0) - pad) * 1e3, (float(x1) + pad) * 1e3)
    ax.set_ylim(0, 1.3e3 * float(top.max()))
    ax.set_aspect("equal", adjustable="box")  # true proportions: the angle as seen
    fig.tight_layout()
    write_replacing(path, lambda tmp: fig.savefig(tmp, dpi=120, format="png"))
    plt.close(fig)
    return path
