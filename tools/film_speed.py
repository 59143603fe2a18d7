"""Time the 3D film's sphere renderer (ooc_dem.app.film3d) on a synthetic frame and print JSON.

A bed of N spheres (default 10^6) at random in a 2 m x 0.5 m x 0.3 m bin, radii in
[0.8, 1] r_max; the two panels of ``ooc-dem animate`` are drawn: the side view (every sphere)
and the cut at mid-width (|z - z_mid| < 1.5 r_max), then put in the film's figure as animate
does (compose: matplotlib's draw of the two pictures). The best of --repeat times, in seconds.
Usage: python tools/film_speed.py [--n N] [--repeat K]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from ooc_dem.app.film3d import SphereSplatter, colour_map


def _figure(W: int, H: int, length: float, yb: float):  # noqa: ANN202
    """The film's figure: two panels of W x H pixels (animate.Scene3D's layout)."""
    from ooc_dem.app.drawing import pyplot

    fig = pyplot().figure(figsize=(W / 100, 2 * H / 100), dpi=100)
    images = []
    for k in range(2):
        ax = fig.add_axes((0.0, 0.5 * (1 - k), 1.0, 0.5))
        ax.set_axis_off()
        blank = np.full((H, W, 3), 255, np.uint8)
        images.append(ax.imshow(blank, extent=(0, length, 0, yb), origin="upper", interpolation="nearest"))
    return fig, images


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--width", type=int, default=1280)
    a = ap.parse_args()
    rng = np.random.default_rng(1)
    length, width, height = 2.0, 0.5, 0.3  # a paper2008-3d-sized bin
    r_max = 0.8 * (0.64 * length * width * height / a.n / (4.0 / 3.0 * np.pi)) ** (1.0 / 3.0)
    r = rng.uniform(0.8 * r_max, r_max, a.n)
    pos = rng.random((a.n, 3)) * [length, height, width]
    vel = rng.normal(0.0, 0.01, (a.n, 3))
    # one panel of the film: the bed and some room above it, equal scale (as animate's)
    H = max(8, int(round(a.width * 1.5 * height / length / 8.0)) * 8)
    yb = length * H / a.width
    sp = SphereSplatter(a.width, H, 0.0, length, 0.0, yb)
    fig, images = _figure(a.width, H, length, yb)
    times: dict[str, list[float]] = {"colour": [], "side": [], "cut": [], "compose": []}
    for _ in range(a.repeat):
        t0 = time.perf_counter()
        rgb = colour_map(np.linalg.norm(vel, axis=1), 0.0, 0.03, "YlOrRd", 0.15)
        t1 = time.perf_counter()
        side = sp.render(pos, r, rgb)
        t2 = time.perf_counter()
        cut = np.abs(pos[:, 2] - 0.5 * width) < 1.5 * r_max
        cut_picture = sp.render(pos[cut], r[cut], rgb[cut])
        t3 = time.perf_counter()
        images[0].set_data(side)
        images[1].set_data(cut_picture)
        fig.canvas.draw()
        np.asarray(fig.canvas.buffer_rgba())
        t4 = time.perf_counter()
        times["colour"].append(t1 - t0)
        times["side"].append(t2 - t1)
        times["cut"].append(t3 - t2)
        times["compose"].append(t4 - t3)
    best = {k: min(v) for k, v in times.items()}
    print(
        json.dumps(
            {
                "spheres": a.n,
                "picture_px": [a.width, H],
                "radius_px": [float(r.min() * sp.scale), float(r.max() * sp.scale)],
                "cut_spheres": int(cut.sum()),
                "covered_px_side": int((side != 255).any(axis=2).sum()),
                "seconds_best_of": a.repeat,
                "seconds": {**{k: round(v, 4) for k, v in best.items()}, "frame": round(sum(best.values()), 4)},
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
