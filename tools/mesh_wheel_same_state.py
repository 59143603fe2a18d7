"""The wheel's contact forces on one stored state of a built-in-wheel run, from the built-in
wheel and from the same wheel as a mesh (tools/make_wheel_meshes.grousered_wheel at a
given tessellation), every contact taken fresh (no spring history, so the two compare
geometry and contact rules, not histories). Prints JSON: per epoch, the contacts and
grains each wheel touches, the grains in two of its parts at once, and the total force
the wheel puts on the grains.

    python tools/mesh_wheel_same_state.py RUN [--epoch STEP ...] [--segments 144]
        [--tip-segments 8]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from make_wheel_meshes import SEGMENTS, TIP_SEGMENTS, grousered_wheel  # noqa: E402

from ooc_dem.engine.stepper import Model  # noqa: E402
from ooc_dem.model.checkpoint import read_epoch_particles, stored_scenario  # noqa: E402
from ooc_dem.physics.d3 import bodies  # noqa: E402
from ooc_dem.physics.d3.layout import BODY_ROW, WHEEL_STATE  # noqa: E402
from ooc_dem.physics.layout import ID_LUG0, ID_RIM, LUG_DIRECTION, discs_of, no_plates  # noqa: E402
from ooc_dem.physics.mesh import mesh_wheel  # noqa: E402
from ooc_dem.physics.plates import plate_scene  # noqa: E402
from ooc_dem.physics.wheel import lug_directions  # noqa: E402
from ooc_dem.storage.opening import open_store  # noqa: E402


def wheel_rows(model: Model, p, ws) -> np.ndarray:
    """Every sphere's rows with the wheel (partner id <= ID_RIM), springs fresh."""
    cp, walls, wg, _ = model.records()
    scene = bodies.body_scene(walls, wg, ws)
    nl = int(wg[0]["nlugs"])
    lugdir = np.empty(max(1, nl), LUG_DIRECTION)
    lug_directions(ws[0]["theta"], nl, lugdir)
    mesh = model.kernel_params().mesh
    d = discs_of(p)
    body = np.zeros(64, BODY_ROW)
    pscene = plate_scene(no_plates().table)
    out = []
    for i in range(len(p)):
        n, full = bodies.body_rows(i, d, cp, scene, False, pscene, lugdir, mesh, body, 0, len(body), model.dt)
        assert not full
        rows = body[:n]
        out.append(rows[(rows["pid"] <= ID_RIM) & (rows["pid"] >= ID_LUG0)].copy())
    return np.concatenate(out)


def summary(rows: np.ndarray) -> dict:
    grains, count = np.unique(rows["disc"], return_counts=True)
    return {
        "contacts": int(len(rows)),
        "grains": int(len(grains)),
        "grains_in_two_parts": int((count > 1).sum()),
        "force_on_grains_N": [float(rows[f].sum()) for f in ("bx", "by", "bz")],
    }


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--epoch", type=int, action="append", help="epoch step (repeatable; default: the current)")
    ap.add_argument("--segments", type=int, default=SEGMENTS, help="the rim's facets")
    ap.add_argument("--tip-segments", type=int, default=TIP_SEGMENTS, help="facets of a lug's rounded tip")
    args = ap.parse_args(argv)
    store = open_store(args.run, repair=False)
    sc = stored_scenario(store.meta or {}, args.run)
    w = sc.wheel
    tri = np.asarray(
        grousered_wheel(
            w.radius,
            w.width,
            w.n_lugs,
            w.lug_tip_radius,
            w.lug_thickness,
            segments=args.segments,
            tip_segments=args.tip_segments,
        ).triangles
    )
    builtin = Model.from_scenario(sc)
    meshed = dataclasses.replace(builtin, mesh=mesh_wheel(tri, 2.0 * sc.soil.r_max))
    out = {"run": args.run, "segments": args.segments, "tip_segments": args.tip_segments, "triangles": len(tri)}
    epochs = []
    for step in args.epoch or [None]:
        p, arrays, attrs = read_epoch_particles(store, args.run, step)
        p.hist_n[:] = 0  # every contact fresh
        ws = np.asarray(arrays["wheel_state"], np.float64).copy().view(WHEEL_STATE).reshape(1)
        epochs.append(
            {
                "step": int(attrs["step"]),
                "builtin": summary(wheel_rows(builtin, p, ws)),
                "mesh": summary(wheel_rows(meshed, p, ws)),
            }
        )
    out["epochs"] = epochs
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
