"""Error bars for an `ooc-dem sweep`: each slip's drawbar pull with its standard error.

The drawbar pull of one run is the mean net traction over the steady window. Successive rows
of the series are correlated (the lugs come round periodically), so the standard error is
taken from batch means: the window cut into BATCHES equal pieces, SE = std(batch means) /
sqrt(BATCHES). Usage: python examples/slip_errorbars.py SWEEP_DIR  (writes
SWEEP_DIR/drawbar_pull_slip_errorbars.csv and .png)
"""

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import ooc_dem  # noqa: E402

BATCHES = 4


def drawbar_pull(run_dir: Path) -> tuple[float, float, float]:
    """(slip, drawbar pull = the steady window's mean net traction, its standard error)."""
    res = ooc_dem.open_run(run_dir)
    s = res.summary
    lo, hi = s["net_traction"]["steady"]["window_s"]
    series = res.series  # a NumPy structured array, one row per output.series_interval
    travel = series["t_travel"]  # s of travel (negative while the wheel settles)
    net = series["net_traction"][(travel >= lo) & (travel <= hi)]
    batches = np.array([b.mean() for b in np.array_split(net, BATCHES)])
    se = batches.std(ddof=1) / np.sqrt(BATCHES)
    return s["slip"]["steady"]["value"], s["net_traction"]["steady"]["value"], float(se)


def main(sweep: Path) -> None:
    rows = [drawbar_pull(d) for d in sorted(sweep.glob("slip_*"))]
    with open(sweep / "drawbar_pull_slip_errorbars.csv", "w") as f:
        f.write("slip,drawbar_pull,standard_error\n")
        for slip, pull, se in rows:
            f.write(f"{slip!r},{pull!r},{se!r}\n")
            print(f"slip {slip:.3f}: drawbar pull {pull:7.3f} ± {se:.3f} N")
    slip, pull, se = np.array(rows).T
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.errorbar(slip, pull, yerr=se, marker="o", capsize=3)
    ax.set_xlabel("slip (-)")
    ax.set_ylabel("drawbar pull (N)")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(sweep / "drawbar_pull_slip_errorbars.png", dpi=120)
    print(f"figure: {sweep / 'drawbar_pull_slip_errorbars.png'}")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
