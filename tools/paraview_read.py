"""Opens exported files with ParaView itself (its Python batch interpreter) and prints, as
JSON, what ParaView read: the reader it chose, the time steps, the points and cells and
the point arrays of the first and the last step, the bounds.

ParaView is not a Python package: this runs under ``pvbatch`` (Debian: ``apt-get install
paraview python3-paraview``; it reads without rendering, but pvbatch wants an X display:
``xvfb-run -a``):

    xvfb-run -a pvbatch tools/paraview_read.py run.xdmf run-wheel.xdmf
"""

from __future__ import annotations

import json
import os
import sys


def describe(source, name: str) -> dict:
    times = list(getattr(source, "TimestepValues", []) or [])
    if not times:
        times = [0.0]
    steps = []
    for t in (times[0], times[-1]):
        source.UpdatePipeline(time=t)
        info = source.GetDataInformation()
        arrays = sorted(source.PointData.keys())
        steps.append(
            {
                "time": t,
                "points": info.GetNumberOfPoints(),
                "cells": info.GetNumberOfCells(),
                "point_arrays": arrays,
                "bounds": list(info.GetBounds()),
            }
        )
    return {"file": name, "reader": source.GetXMLName(), "time_steps": len(times), "first": steps[0], "last": steps[-1]}


def main(argv: list[str]) -> int:
    from paraview.simple import OpenDataFile

    if not argv:
        print(__doc__, file=sys.stderr)
        return 2
    out = []
    for name in argv:
        # ParaView's XDMF 3 reader joins a bare file name's (empty) directory with the heavy
        # data's relative path by string concatenation ('a.xdmfa.h5'): give it a full path
        name = os.path.abspath(name)
        src = OpenDataFile(name)
        if src is None:
            print(f"paraview_read: ParaView has no reader for {name}", file=sys.stderr)
            return 2
        out.append(describe(src, name))
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
