"""The figures of a wheel run.

* ``make_figures(out_dir)`` writes ``OUT/figures/series.png`` (time series),
  ``deformation.png`` (the paper's Figs. 5-6: initial bed in horizontal layers,
  final bed with each disc in its initial layer colour, the wheel with its lugs)
  and ``displacement.png`` (gridded displacement vectors); a 3D run adds its mid-width
  slice, rut and lateral-flow views and the wheel mesh (views3d.py).

The drawing itself (headless pyplot, discs at true radii, the wheel) is drawing.py's; the
run's files are read through runfiles.py (validated: a run directory is untrusted input).
The text table of a run is tables.py's, the drawbar-pull--slip curve sweep_slip.py's.
"""

from __future__ import annotations

import math
import os
import stat
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

import numpy as np
from numpy.typing import NDArray

from ..model.fields import displacements, gridded_displacement, layer_index
from ..physics.layout import AX_X, AX_Y, AX_Z, WS_THETA, WS_X, WS_Y
from .drawing import LAYER_COLOURS, draw_discs, draw_wheel, layer_count, panel_size, pyplot, save_figure
from .runfiles import (
    InitialBed,
    RunFileError,
    has_store,
    read_final,
    read_final_particles,
    read_initial,
    read_initial_z,
    read_run_scenario,
    read_series,
    read_summary,
    run_file,
    summary_value,
    summary_window,
)

if TYPE_CHECKING:
    from ..model.scenario import Scenario
    from ..model.state import Particles

# a state as the figures draw it: id, x, y, r and the wheel state (None: no wheel to draw)
Drawn: TypeAlias = tuple[
    NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None
]
# the same as make_figures is given it, any numeric arrays
FinalArrays: TypeAlias = tuple[NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any] | None]
# a run's series.csv as read_series gives it: its columns by name
Series: TypeAlias = dict[str, NDArray[np.float64]]


def _series_figure(series: Series, summary: dict[str, Any] | None, sc: Scenario | None, path: Path) -> Path:
    plt = pyplot()
    t = series["t_travel"] if "t_travel" in series else series["t"]  # read_series: one is there
    steady = summary_window(summary, "slip", "steady")
    if steady is None and sc is not None:
        steady = (sc.output.steady_start, min(sc.output.steady_end, sc.wheel.travel_time))
    fig, axes = plt.subplots(4, 1, sharex=True, figsize=(9, 9.5), constrained_layout=True)
    a_slip, a_tr, a_tq, a_sk = axes

    a_slip.plot(t, series["slip"], color="C0", lw=1.0)
    a_slip.set_ylabel("slip s [-]")
    ws = summary_value(summary, "slip", "steady")
    if ws is not None and math.isfinite(ws):
        a_slip.axhline(ws, color="C0", ls=":", lw=1.0, label=f"steady mean {ws:.3f}")

    a_tr.plot(t, series["net_traction"], color="C1", lw=0.8, label="net traction")
    a_tr.plot(t, series["gross_traction"], color="C2", lw=0.8, label="gross traction (torque / R)")
    db = series.get("drawbar")
    if db is not None and np.any(np.abs(db[np.isfinite(db)]) > 0):
        a_tr.plot(t, -db, color="k", ls="--", lw=1.0, label="drawbar load")
    a_tr.set_ylabel("traction [N]")
    a_tr.legend(loc="lower right", fontsize=8, ncol=3)

    a_tq.plot(t, series["torque"], color="C3", lw=0.8)
    a_tq.set_ylabel("torque [N m]")

    a_sk.plot(t, 1e3 * series["sinkage"], color="C4", lw=1.0)
    a_sk.set_ylabel("sinkage [mm]")
    a_sk.set_xlabel("travel time [s]  (0 = end of the wheel's settling)")

    for k, ax in enumerate(axes):
        if steady is not None:
            ax.axvspan(
                steady[0], steady[1], color="0.85", alpha=0.6, zorder=0, label="steady window" if k == 0 else None
            )
        if len(t) and np.nanmin(t) < 0:
            ax.axvline(0.0, color="0.4", lw=0.8, ls="-.")
        ax.grid(True, lw=0.3, alpha=0.6)
    if a_slip.get_legend_handles_labels()[0]:
        a_slip.legend(loc="lower right", fontsize=8)
    name = (summary or {}).get("scenario") or (sc.name if sc is not None else "")
    title = f"Wheel performance — {name}" if name else "Wheel performance"
    if steady is not None:
        title += f"  (shaded: steady window {steady[0]:g}–{steady[1]:g} s)"
    fig.suptitle(title, fontsize=11)
    return save_figure(fig, path)


def _placement(
    sc: Scenario, x: NDArray[np.float64], y: NDArray[np.float64], r: NDArray[np.float64]
) -> tuple[float, float]:
    """The wheel's initial centre, as the engine places it (run_setup.place_wheel): above x0 with the
    lug tips drop_gap above the highest disc under the wheel; theta = 0."""
    w = sc.wheel
    if len(x) == 0:
        return w.x0, w.lug_tip_radius + w.drop_gap
    under = np.abs(x - w.x0) < w.lug_tip_radius + sc.soil.r_max
    top = float((y[under] + r[under]).max()) if under.any() else float((y + r).max())
    return w.x0, top + w.lug_tip_radius + w.drop_gap


def _zoom(
    sc: Scenario | None,
    series: Series | None,
    ws_final: NDArray[np.float64] | None,
    bed_x: NDArray[np.float64],
    bed_y: NDArray[np.float64],
    bed_r: NDArray[np.float64],
    surface: float,
) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1): from the wheel's start - 1.5 R to its final x + 1.5 R, floor to wheel top."""
    lo_x = float(np.min(bed_x - bed_r)) if len(bed_x) else 0.0
    hi_x = float(np.max(bed_x + bed_r)) if len(bed_x) else 1.0
    if sc is not None:
        lo_x = min(lo_x, 0.0)
        hi_x = max(hi_x, sc.bin.length)
    y0 = min(0.0, float(np.min(bed_y - bed_r))) if len(bed_y) else 0.0
    y1 = surface
    if sc is not None and sc.wheel.enabled and ws_final is not None:
        R = sc.wheel.radius
        start, y_start = _placement(sc, bed_x, bed_y, bed_r)
        xa = max(lo_x, min(start, ws_final[0]) - 1.5 * R)
        xb = min(hi_x, max(start, ws_final[0]) + 1.5 * R)
        y1 = max(surface, ws_final[1] + sc.wheel.lug_tip_radius, y_start + sc.wheel.lug_tip_radius)
        if series is not None and len(series.get("y", [])):
            y1 = max(y1, float(np.nanmax(series["y"])) + sc.wheel.lug_tip_radius)
    else:
        xa, xb = lo_x, hi_x
    pad = 0.02 * (y1 - y0)
    return xa, xb, y0 - pad, y1 + pad


def _deformation_figure(init: InitialBed, final: Drawn, sc: Scenario | None, series: Series | None, path: Path) -> Path:
    plt = pyplot()
    iid, ix, iy, ir, surface = init
    fid, fx, fy, fr, ws = final
    n_layers = layer_count(surface, ir)
    layer = layer_index(iy, surface, n_layers)
    colours = np.array(LAYER_COLOURS)[layer % 2]
    # final discs take the layer colour of the same id
    fcol = np.full(len(fid), "#4a7fbf", dtype=object)  # discs not in the initial bed (none expected)
    if len(iid):
        order = np.argsort(iid, kind="stable")
        pos = np.clip(np.searchsorted(iid[order], fid), 0, len(iid) - 1)
        known = iid[order][pos] == fid
        fcol[known] = colours[order][pos[known]]

    xa, xb, ya, yb = _zoom(sc, series, ws, ix, iy, ir, surface)
    width_in, panel_h = panel_size(xb - xa, yb - ya)
    fig, axes = plt.subplots(
        2, 1, figsize=(width_in + 0.8, 2 * panel_h + 1.0), sharex=True, sharey=True, constrained_layout=True
    )
    a0, a1 = axes
    m0 = (ix + ir > xa) & (ix - ir < xb)
    draw_discs(a0, ix[m0], iy[m0], ir[m0], colours[m0])
    m1 = (fx + fr > xa) & (fx - fr < xb)
    draw_discs(a1, fx[m1], fy[m1], fr[m1], fcol[m1])
    wheel_ws = ws if sc is not None and sc.wheel.enabled else None  # None: no wheel drawn
    wheel_on = wheel_ws is not None
    if sc is not None and wheel_ws is not None:
        w = sc.wheel
        x_start, y_start = _placement(sc, ix, iy, ir)
        draw_wheel(
            a0,
            x_start,
            y_start,
            0.0,
            w.radius,
            w.n_lugs,
            w.lug_tip_radius,
            w.lug_thickness,
            fill=False,
            color="0.35",
            linestyle="--",
        )
        draw_wheel(
            a1,
            wheel_ws[WS_X],
            wheel_ws[WS_Y],
            wheel_ws[WS_THETA],
            w.radius,
            w.n_lugs,
            w.lug_tip_radius,
            w.lug_thickness,
        )
    for ax in axes:
        ax.axhline(surface, color="0.3", lw=0.6, ls=":", zorder=3)
        ax.set_xlim(xa, xb)
        ax.set_ylim(ya, yb)
        ax.set_aspect("equal")
        ax.set_ylabel("y [m]")
    a1.set_xlabel("x [m]")
    a0.set_title(
        f"initial bed: {n_layers} horizontal layers of {1e3 * surface / n_layers:.1f} mm "
        f"(dotted: initial surface" + ("; dashed: wheel as placed)" if wheel_on else ")"),
        fontsize=10,
    )
    title = "final state: each disc keeps its initial layer colour"
    if wheel_ws is not None:
        title += f"; wheel at x = {wheel_ws[WS_X]:.3f} m, θ = {math.degrees(wheel_ws[WS_THETA]):.0f}°"
    a1.set_title(title, fontsize=10)
    return save_figure(fig, path)


def _displacement_figure(
    init: InitialBed, final: Drawn, sc: Scenario | None, series: Series | None, path: Path
) -> Path:
    plt = pyplot()
    iid, ix, iy, ir, surface = init
    fid, fx, fy, fr, ws = final
    dx, dy = displacements(iid, ix, iy, fid, fx, fy)
    xa, xb, ya, yb = _zoom(sc, series, ws, ix, iy, ir, surface)
    dmean = 2.0 * float(np.mean(ir)) if len(ir) else 0.004
    cell = max(2.5 * dmean, (xb - xa) / 45.0)
    sel = (ix >= xa) & (ix <= xb)
    grid = gridded_displacement(
        ix[sel], iy[sel], dx[sel], dy[sel], cell, extent=(xa, xb, max(ya, 0.0), surface), min_count=2
    )
    mag = np.hypot(grid.u, grid.v)
    finite = np.isfinite(mag)
    # true scale unless arrows would overlap badly; the key gives the scale either way
    big = float(np.percentile(mag[finite], 98)) if finite.any() else 0.0
    scale = 1.0 if big <= 1.5 * cell or big == 0.0 else big / (1.5 * cell)

    width_in, panel_h = panel_size(xb - xa, yb - ya)
    fig, ax = plt.subplots(figsize=(width_in + 2.0, panel_h + 0.9), constrained_layout=True)
    m0 = (ix + ir > xa) & (ix - ir < xb)
    draw_discs(ax, ix[m0], iy[m0], ir[m0], "#eeeeee", edgecolor="#cccccc", linewidth=0.1, zorder=0)
    if finite.any():
        q = ax.quiver(
            grid.x[finite],
            grid.y[finite],
            grid.u[finite],
            grid.v[finite],
            1e3 * mag[finite],
            angles="xy",
            scale_units="xy",
            scale=scale,
            cmap="viridis",
            width=0.0025,
            zorder=2,
        )
        cb = fig.colorbar(q, ax=ax, shrink=0.8)
        cb.set_label("displacement [mm]")
        ref = _nice(big if big > 0 else cell)
        ax.quiverkey(
            q,
            0.97,
            0.95,
            ref,
            f"{1e3 * ref:g} mm",
            labelpos="W",
            coordinates="axes",
            color="k",
            fontproperties={"size": 8},
        )
    wheel_ws = ws if sc is not None and sc.wheel.enabled else None  # None: no wheel drawn
    wheel_on = wheel_ws is not None
    if sc is not None and wheel_ws is not None:
        w = sc.wheel
        draw_wheel(
            ax,
            wheel_ws[WS_X],
            wheel_ws[WS_Y],
            wheel_ws[WS_THETA],
            w.radius,
            w.n_lugs,
            w.lug_tip_radius,
            w.lug_thickness,
            fill=False,
            color="0.2",
            zorder=3,
        )
    ax.axhline(surface, color="0.3", lw=0.6, ls=":", zorder=1)
    ax.set_xlim(xa, xb)
    ax.set_ylim(ya, yb)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    how = "true scale" if scale == 1.0 else f"scaled ×{1 / scale:.2g}"
    ax.set_title(
        f"soil displacement (final − initial), mean over {1e3 * cell:.0f} mm cells of initial "
        f"position; arrows {how}" + ("; wheel at its final position" if wheel_on else ""),
        fontsize=9,
    )
    return save_figure(fig, path)


def _nice(v: float) -> float:
    """A round number (1, 2, 5 x 10^k) not above v."""
    if not v > 0:
        return 1e-3
    e = math.floor(math.log10(v))
    for m in (5.0, 2.0, 1.0):
        if m * 10.0**e <= v:
            return m * 10.0**e
    return 10.0**e


# the figures make_figures writes for a wheel run (into OUT/figures/)
SERIES_FIGURE, DEFORMATION_FIGURE, DISPLACEMENT_FIGURE = "series.png", "deformation.png", "displacement.png"
FIGURE_NAMES = (SERIES_FIGURE, DEFORMATION_FIGURE, DISPLACEMENT_FIGURE)


def figure_files(sc: Scenario) -> tuple[str, ...]:
    """The files ``make_figures`` writes for a wheel run of scenario sc, relative to its
    directory (3D adds the mid-width slice, rut and lateral-flow views and the wheel mesh)."""
    names: tuple[str, ...] = FIGURE_NAMES
    beside: tuple[str, ...] = ()
    if sc.dim == 3:
        from .views3d import LATERAL_FIGURE, MIDWIDTH_FIGURE, RUT_FIGURE, WHEEL_MESH

        names, beside = names + (MIDWIDTH_FIGURE, RUT_FIGURE, LATERAL_FIGURE), (WHEEL_MESH,)
    return tuple(f"figures/{n}" for n in names) + beside


def make_figures(out_dir: str | os.PathLike[str], final: FinalArrays | None = None) -> list[Path]:
    """Write the run's figures into ``OUT/figures/``; return their paths.

    ``final`` = (id, x, y, r, wheel_state) skips reading the store's last epoch.
    Figures whose inputs are missing (no ``series.csv``, no ``initial.npz``) are
    skipped.
    """
    out = Path(out_dir)
    fig_dir = out / "figures"
    if os.path.lexists(fig_dir) and not stat.S_ISDIR(os.lstat(fig_dir).st_mode):
        # a symlink here would send the figures (and their replacement) anywhere
        raise RunFileError(f"{fig_dir}: not a directory of the run (a symlink or a file; refused)")
    fig_dir.mkdir(parents=True, exist_ok=True)
    sc = read_run_scenario(out)
    summary = read_summary(out, complete=False)
    series_file = run_file(out, "series.csv")
    series = read_series(series_file) if series_file is not None else None
    written: list[Path] = []
    if series is not None:
        written.append(_series_figure(series, summary, sc, fig_dir / SERIES_FIGURE))
    initial_file = run_file(out, "initial.npz")
    if initial_file is not None and final is None and not has_store(out):
        # a `--backend memory` run's store lived only in its process: no final state to draw
        initial_file = None
    if initial_file is not None:
        if final is None:
            final = read_final(out)
        init = read_initial(initial_file, len(final[0]), sc)
        fid, fx, fy, fr, ws = final
        final = (
            np.asarray(fid, np.int64),
            np.asarray(fx, np.float64),
            np.asarray(fy, np.float64),
            np.asarray(fr, np.float64),
            None if ws is None else np.asarray(ws, np.float64),
        )
        written.append(_deformation_figure(init, final, sc, series, fig_dir / DEFORMATION_FIGURE))
        written.append(_displacement_figure(init, final, sc, series, fig_dir / DISPLACEMENT_FIGURE))
        init_z = read_initial_z(initial_file, len(init[0]))
        if sc is not None and sc.dim == 3 and sc.wheel.enabled and init_z is not None:
            # the 3D wheel's own views: mid-width slice, rut, lateral flow, wheel mesh
            p, ws = read_final_particles(out)
            written += _views_3d(out, sc, (init, init_z), p, ws, series)
    return written


def _views_3d(
    out: Path,
    sc: Scenario,
    init: tuple[InitialBed, NDArray[np.float64]],
    final_p: Particles,
    ws: NDArray[np.float64],
    series: Series | None,
) -> list[Path]:
    """The 3D views of a run (module doc). init: (id, x, y, r, surface) and z of the
    initial bed; final_p: the final Particles."""
    from ..engine.stepper import wheel_z0
    from .views3d import (
        LATERAL_FIGURE,
        MIDWIDTH_FIGURE,
        RUT_FIGURE,
        WHEEL_MESH,
        _grid,
        _match,
        lateral_map,
        surface_map,
        write_wheel_vtk,
    )

    out = Path(out)
    fig_dir = out / "figures"
    (iid, ix, iy, ir, surface), iz = init
    fid, fpos, fr = final_p.id, final_p.pos, final_p.r
    fx, fy, fz = fpos[:, AX_X], fpos[:, AX_Y], fpos[:, AX_Z]
    z0 = wheel_z0(sc)
    band = 2.0 * sc.soil.r_max
    written = []
    # mid-width slice: the spheres whose final centres lie within the band; the initial
    # panel shows those and the ones that started in it (each keeps its layer colour)
    mf = np.abs(fz - z0) < band
    mi = np.abs(iz - z0) < band
    mi[_match(iid, fid[mf])] = True
    written.append(
        _deformation_figure(
            (iid[mi], ix[mi], iy[mi], ir[mi], surface),
            (fid[mf], fx[mf], fy[mf], fr[mf], ws),
            sc,
            series,
            fig_dir / MIDWIDTH_FIGURE,
        )
    )
    plt = pyplot()
    cell, nx, nz = _grid(sc)
    extent = (0.0, nx * cell, 0.0, nz * cell)
    w = sc.wheel
    rut = surface_map(sc, fx, fy, fz, fr) - surface_map(sc, ix, iy, iz, ir)
    k = _match(iid, fid)
    lat = lateral_map(sc, ix[k], iz[k], fz - iz[k])
    for name, data, label, cmap in (
        (RUT_FIGURE, 1e3 * rut, "surface change (final − initial) [mm]", "RdBu"),
        (LATERAL_FIGURE, 1e3 * lat, "mean lateral displacement dz [mm] (by initial cell)", "PuOr"),
    ):
        lim = float(np.nanmax(np.abs(data))) if np.isfinite(data).any() else 1.0
        fig, ax = plt.subplots(figsize=(10, 10 * sc.bin.width / sc.bin.length + 1.2), constrained_layout=True)
        im = ax.imshow(
            data.T,
            origin="lower",
            extent=extent,
            cmap=cmap,
            vmin=-lim,
            vmax=lim,
            aspect="equal",
            interpolation="nearest",
        )
        for zb in (z0 - 0.5 * w.width, z0 + 0.5 * w.width):
            ax.axhline(zb, color="k", lw=0.8, ls="--")
        ax.axvline(w.x0, color="0.3", lw=0.6, ls=":")
        ax.axvline(float(ws[WS_X]), color="k", lw=0.8)
        ax.set_xlabel("x [m] (travel)")
        ax.set_ylabel("z [m] (across)")
        ax.set_title(f"{sc.name}: {label}; dashed: wheel width, dotted/solid: start/final axle x", fontsize=9)
        fig.colorbar(im, ax=ax, shrink=0.8)
        written.append(save_figure(fig, fig_dir / name))
    written.append(write_wheel_vtk(out / WHEEL_MESH, sc, ws))
    return written
