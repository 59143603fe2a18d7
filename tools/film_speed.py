"""Time the 3D film's sphere renderer (ooc_dem.app.film3d) on a synthetic frame and print JSON.

A bed of N spheres (default 10^6) filling a bin, radii in [r_min, r_max]; the two panels of
``ooc-dem animate`` are drawn: the side view (every sphere) and the cut at mid-width
(|z - z_mid| < 1.5 r_max). Usage: python tools/film_speed.py [--n N] [--repeat K]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from ooc_dem.app.film3d import SphereSplatter, colour_map


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
    H = int(round(a.width * 1.1 * height / length / 16.0)) * 16
    yb = 1.1 * height * 0 + length * H / a.width
    sp = SphereSplatter(a.width, H, 0.0, length, 0.0, yb)
    times: dict[str, list[float]] = {"colour": [], "side": [], "cut": []}
    for _ in range(a.repeat):
        t0 = time.perf_counter()
        rgb = colour_map(np.linalg.norm(vel, axis=1), 0.0, 0.03)
        t1 = time.perf_counter()
        side = sp.render(pos, r, rgb)
        t2 = time.perf_counter()
        cut = np.abs(pos[:, 2] - 0.5 * width) < 1.5 * r_max
        sp.render(pos[cut], r[cut], rgb[cut])
        t3 = time.perf_counter()
        times["colour"].append(t1 - t0)
        times["side"].append(t2 - t1)
        times["cut"].append(t3 - t2)
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
