#!/usr/bin/env python
"""How far to the side of a 3D wheel the soil moves: the lateral extent of the wheel's zone
of influence, from a run's trajectory, and the bin width that keeps the side walls out of it.

A side wall changes the wheel's numbers only through the soil it holds: it stops the soil's
motion where it stands. So the wall must stand where the wheel no longer moves the soil.
Between the frame at the start of travel (``wheel.settle_time``, or --t0) and the last frame
(or --t1), this takes every sphere that started over the stretch the wheel's axle travelled
(x between its two positions), bins it by its lateral distance from the wheel's nearer side
face, e = |z - z0| - b/2 (e < 0: under the wheel), and prints per bin the mean displacement
magnitude and its components (dx along the travel, dy up, dz_out away from the wheel).

The same is done ahead of the wheel (the spheres of its track that started beyond the
lugs' front at the end, binned by their distance from it): how far ahead the end wall must
stay. The displacement that is not the wheel's (the bed still creeping under gravity) is the
floor: the mean over the outermost quarter of the bins (--floor-from sets where it starts).
The zone's edge for a fraction p (--fractions, default 2 % and 5 %) is the smallest e beyond
which every bin's mean displacement above the floor stays below p times that under the wheel;
a bin this wide keeps the side walls at least that far from the wheel: b + 2 e_p.

    python tools/influence_zone.py RUN                   # JSON: the profile and the edges
    python tools/influence_zone.py RUN --png zone.png    # and the profile as a figure

Reads two frames of the run (each one value per sphere of the bed, in memory: a tool for
runs that fit in RAM; the engine's out-of-core path never does this).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ooc_dem.physics.layout import AX_X, AX_Y, AX_Z, WS_X  # noqa: E402


def nearest_frame(times: np.ndarray, t: float) -> int:
    """Index of the frame whose time is closest to t."""
    return int(np.argmin(np.abs(np.asarray(times) - t)))


def _binned(d: np.ndarray, e: np.ndarray, side: np.ndarray, bin_width: float) -> list[dict]:
    """Per bin of e: count and mean displacement |d|, dx, dy and dz times side (away from the
    wheel's mid-plane)."""
    if not e.size:
        return []
    k = np.floor(e / bin_width).astype(np.int64)
    rows = []
    for b in range(int(k.min()), int(k.max()) + 1):
        m = k == b
        if not m.any():
            continue
        db = d[m]
        rows.append(
            {
                "e_lo": b * bin_width,
                "e_hi": (b + 1) * bin_width,
                "n": int(m.sum()),
                "disp": float(np.linalg.norm(db, axis=1).mean()),
                "dx": float(db[:, AX_X].mean()),
                "dy": float(db[:, AX_Y].mean()),
                "dz_out": float((db[:, AX_Z] * side[m]).mean()),
            }
        )
    return rows


def lateral_profile(
    pos0: np.ndarray, pos1: np.ndarray, x_range: tuple[float, float], z0: float, half_width: float, bin_width: float
) -> list[dict]:
    """Per lateral bin of e = |z - z0| - half_width (initial positions, spheres whose initial x
    is in x_range): count and mean displacement |d|, dx, dy and dz away from the wheel."""
    x, z = pos0[:, AX_X], pos0[:, AX_Z]
    lo, hi = x_range
    sel = (x >= lo) & (x <= hi)
    return _binned(
        pos1[sel] - pos0[sel], np.abs(z[sel] - z0) - half_width, np.where(z[sel] >= z0, 1.0, -1.0), bin_width
    )


def ahead_profile(
    pos0: np.ndarray, pos1: np.ndarray, front: float, z0: float, half_width: float, bin_width: float
) -> list[dict]:
    """The same ahead of the wheel: spheres of its track (|z - z0| <= half_width) that started
    at x >= front (the lugs' front at the end), binned by e = x - front."""
    x, z = pos0[:, AX_X], pos0[:, AX_Z]
    sel = (x >= front) & (np.abs(z - z0) <= half_width)
    return _binned(pos1[sel] - pos0[sel], x[sel] - front, np.where(z[sel] >= z0, 1.0, -1.0), bin_width)


def edges_of(rows: list[dict], fractions: list[float], floor: float, wheel: float) -> dict:
    """Per fraction p, the smallest e >= 0 beyond which every bin's displacement above the floor
    is below p (wheel - floor) (None: not reached)."""
    outside = [r for r in rows if r["e_lo"] >= 0.0]
    edges = {}
    for p in fractions:
        # the edge is the start of the bin after the last one at or above p
        above = [j for j, r in enumerate(outside) if r["disp"] - floor >= p * (wheel - floor)]
        j = above[-1] + 1 if above else 0
        edges[f"{p:g}"] = outside[j]["e_lo"] if j < len(outside) else None
    return edges


def zone_edges(rows: list[dict], fractions: list[float], floor_from: float | None) -> dict:
    """The floor (mean displacement of the bins from floor_from on, default: the outermost
    quarter), the mean under the wheel (e < 0), and per fraction p the smallest e beyond which
    every bin's displacement above the floor is below p times the wheel's (None: not reached)."""
    outside = [r for r in rows if r["e_lo"] >= 0.0]
    under = [r for r in rows if r["e_hi"] <= 0.0]
    if not outside or not under:
        raise ValueError("the run's bin has no spheres under the wheel or beside it")
    if floor_from is None:
        floor_from = outside[-1]["e_hi"] * 0.75
    far = [r for r in outside if r["e_lo"] >= floor_from] or outside[-1:]
    floor = float(np.average([r["disp"] for r in far], weights=[r["n"] for r in far]))
    wheel = float(np.average([r["disp"] for r in under], weights=[r["n"] for r in under]))
    return {
        "floor": floor,
        "floor_from": floor_from,
        "under_wheel": wheel,
        "edges": edges_of(rows, fractions, floor, wheel),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="a 3D wheel run's directory (with trajectory frames)")
    ap.add_argument("--t0", type=float, help="start time (default: wheel.settle_time)")
    ap.add_argument("--t1", type=float, help="end time (default: the last frame)")
    ap.add_argument("--bin", type=float, help="lateral bin width in m (default: 2 r_max)")
    ap.add_argument("--fractions", default="0.02,0.05")
    ap.add_argument("--floor-from", type=float, help="e (m) from which bins make the floor")
    ap.add_argument("--png", help="write the profile as a figure")
    a = ap.parse_args(argv)
    from ooc_dem.api import load_scenario
    from ooc_dem.engine.stepper import wheel_z0
    from ooc_dem.app.trajectory_format import TrajectoryError
    from ooc_dem.app.trajectory_read import Trajectory
    from ooc_dem.model.scenario import ScenarioError

    run = Path(a.run)
    try:
        fractions = [float(p) for p in a.fractions.split(",")]
        if not all(0.0 < p < 1.0 for p in fractions):
            raise ValueError(f"--fractions: each must be between 0 and 1, got {a.fractions}")
        if a.bin is not None and not 0.0 < a.bin < 1.0:
            raise ValueError(f"--bin: a width in m between 0 and 1, got {a.bin}")
        sc = load_scenario(run / "scenario.toml")
        if sc.dim != 3 or not sc.wheel.enabled:
            raise ValueError(
                f"{run}: needs a 3D wheel run (this one is {sc.dim}D{'' if sc.wheel.enabled else ', no wheel'})"
            )
        traj = Trajectory.of_run(run)
        if len(traj) < 2:
            raise ValueError(f"{run}: needs a 3D wheel run with at least two trajectory frames")
    except (ScenarioError, TrajectoryError, OSError, ValueError) as e:
        print(f"influence_zone: {e}", file=sys.stderr)
        return 2
    i0 = nearest_frame(traj.times, sc.wheel.settle_time if a.t0 is None else a.t0)
    i1 = len(traj) - 1 if a.t1 is None else nearest_frame(traj.times, a.t1)
    f0, f1 = traj[i0], traj[i1]
    if not np.array_equal(f0["id"], f1["id"]):
        print("influence_zone: the two frames hold different spheres", file=sys.stderr)
        return 2
    xw0, xw1 = float(f0["wheel_state"][WS_X]), float(f1["wheel_state"][WS_X])
    bin_width = a.bin or 2.0 * sc.soil.r_max
    z0, half_width = wheel_z0(sc), 0.5 * sc.wheel.width
    rows = lateral_profile(f0["pos"], f1["pos"], (min(xw0, xw1), max(xw0, xw1)), z0, half_width, bin_width)
    try:
        zone = zone_edges(rows, fractions, a.floor_from)
    except ValueError as e:  # e.g. --t0 and --t1 on one frame: the wheel did not travel
        print(f"influence_zone: {run}, t = {traj.times[i0]:g}-{traj.times[i1]:g} s: {e}", file=sys.stderr)
        return 2
    front = max(xw0, xw1) + sc.wheel.lug_tip_radius
    ahead = ahead_profile(f0["pos"], f1["pos"], front, z0, half_width, bin_width)
    report = {
        "run": str(run),
        "t0": float(traj.times[i0]),
        "t1": float(traj.times[i1]),
        "wheel_x": [xw0, xw1],
        "wheel_width": sc.wheel.width,
        "bin_width_m": sc.bin.width,
        "wall_gap_m": 0.5 * (sc.bin.width - sc.wheel.width),
        "lateral_bin": bin_width,
        **zone,
        "bin_width_for": {p: (None if e is None else sc.wheel.width + 2.0 * e) for p, e in zone["edges"].items()},
        "profile": rows,
        "ahead": {
            "front_x": front,
            "end_wall_gap_m": sc.bin.length - front,
            "edges": edges_of(ahead, fractions, zone["floor"], zone["under_wheel"]),
            "profile": ahead,
        },
    }
    if a.png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        e = np.array([0.5 * (r["e_lo"] + r["e_hi"]) for r in rows])
        fig, (ax, lx) = plt.subplots(1, 2, figsize=(12, 4))
        for key, label in (("disp", "|d|"), ("dy", "dy (up)"), ("dz_out", "dz (outward)"), ("dx", "dx (travel)")):
            ax.plot(100 * e, 1000 * np.array([r[key] for r in rows]), marker=".", label=label)
        rel = (np.array([r["disp"] for r in rows]) - zone["floor"]) / (zone["under_wheel"] - zone["floor"])
        lx.semilogy(
            100 * e, np.where(rel > 0, rel, np.nan), marker=".", c="C0", label="beside the wheel (e from its side face)"
        )
        if ahead:
            ea = np.array([0.5 * (r["e_lo"] + r["e_hi"]) for r in ahead])
            ra = (np.array([r["disp"] for r in ahead]) - zone["floor"]) / (zone["under_wheel"] - zone["floor"])
            lx.semilogy(
                100 * ea,
                np.where(ra > 0, ra, np.nan),
                marker=".",
                c="C3",
                label="ahead of the lugs' front at the end (e = x - front)",
            )
        lx.legend(fontsize=7, loc="lower left")
        for p, edge in zone["edges"].items():
            lx.axhline(float(p), ls=":", c="gray")
            for axis in (ax, lx):
                if edge is not None:
                    axis.axvline(100 * edge, ls="--", c="gray")
            if edge is not None:
                lx.text(100 * edge, float(p), f" {float(p):.0%}: e = {100 * edge:.1f} cm", va="bottom", fontsize=8)
        for axis in (ax, lx):
            axis.axvline(0, c="k", lw=0.8)
        ax.set_xlabel("lateral distance from the wheel's side face e (cm; < 0 under the wheel)", fontsize=8)
        lx.set_xlabel("distance e (cm) from the wheel's side face (blue) or the lugs' front (red)", fontsize=8)
        ax.axhline(0, c="k", lw=0.5)
        ax.set_ylabel("mean displacement (mm)")
        ax.set_title(
            f"{run.name}: soil displaced between t = {traj.times[i0]:.2f} and {traj.times[i1]:.2f} s", fontsize=9
        )
        ax.legend(fontsize=8)
        lx.set_ylabel("(|d| - floor) / (|d| under the wheel - floor)")
        lx.set_title(
            f"floor {1e3 * zone['floor']:.4f} mm (e >= {100 * zone['floor_from']:.0f} cm); "
            f"side wall at e = {100 * report['wall_gap_m']:.0f} cm",
            fontsize=9,
        )
        fig.tight_layout()
        fig.savefig(a.png, dpi=120)
        report["png"] = a.png
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
