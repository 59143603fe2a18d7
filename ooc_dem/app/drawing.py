"""Matplotlib's part of the figures: headless pyplot, discs at their true radii, the wheel
with its lugs, panel sizes, and saving a figure whole (plots.py, views3d, animate.py,
sweep_slip.py draw with these).

Everything runs headless (Agg backend); discs are drawn at their true radii with one
``EllipseCollection``, so ~10^4 discs render in about a second.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..storage.atomic import write_replacing

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.collections import EllipseCollection
    from matplotlib.figure import Figure
    from numpy.typing import ArrayLike

LAYER_COLOURS = ("#e3c79a", "#8a5a2b")  # light sand / dark soil, alternating
DPI = 150


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (no display), imported when first needed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def draw_discs(
    ax: Axes,
    x: ArrayLike,
    y: ArrayLike,
    r: ArrayLike,
    facecolors: str | Iterable[str],
    edgecolor: str = "#3a2a1a",
    linewidth: float = 0.15,
    zorder: float = 1,
    alpha: float | None = None,
) -> EllipseCollection:
    """All discs as one EllipseCollection at true radius (data units)."""
    from matplotlib.collections import EllipseCollection
    from matplotlib.colors import to_rgba_array

    facecolors = to_rgba_array(facecolors if isinstance(facecolors, str) else list(facecolors))
    d = 2.0 * np.asarray(r, dtype=np.float64)
    coll = EllipseCollection(
        d,
        d,
        np.zeros_like(d),
        units="xy",
        offsets=np.column_stack([x, y]),
        offset_transform=ax.transData,
        facecolors=facecolors,
        edgecolors=edgecolor,
        linewidths=linewidth,
        zorder=zorder,
        alpha=alpha,
    )
    ax.add_collection(coll)
    return coll


def draw_wheel(
    ax: Axes,
    x: float,
    y: float,
    theta: float,
    radius: float,
    n_lugs: int,
    lug_tip_radius: float,
    lug_thickness: float = 0.002,
    fill: bool = True,
    zorder: float = 5,
    color: str = "k",
    alpha: float = 1.0,
    linestyle: str = "-",
) -> None:
    """Rim circle plus ``n_lugs`` radial lugs (from R to the tip) at angles theta + 2 pi k / n."""
    from matplotlib.patches import Circle, Polygon

    ax.add_patch(
        Circle(
            (x, y),
            radius,
            facecolor="#b8c4d0" if fill else "none",
            edgecolor=color,
            linewidth=1.0,
            zorder=zorder,
            alpha=alpha,
            linestyle=linestyle,
        )
    )
    half = 0.5 * lug_thickness
    for k in range(int(n_lugs)):
        phi = theta + 2.0 * math.pi * k / n_lugs
        ux, uy = math.cos(phi), math.sin(phi)
        nx, ny = -uy, ux
        pts = [
            (x + ux * rr + nx * s, y + uy * rr + ny * s)
            for rr, s in ((radius, -half), (lug_tip_radius, -half), (lug_tip_radius, half), (radius, half))
        ]
        ax.add_patch(
            Polygon(
                pts,
                closed=True,
                facecolor=color if fill else "none",
                edgecolor=color,
                linewidth=0.8,
                zorder=zorder + 0.1,
                alpha=alpha,
                linestyle=linestyle,
            )
        )
    ax.plot([x], [y], marker="+", color=color, markersize=6, zorder=zorder + 0.2, alpha=alpha)


def panel_size(xr: float, yr: float, max_w: float = 10.0, max_h: float = 6.0) -> tuple[float, float]:
    """Inches (width, height) of an equal-aspect panel of data size xr x yr within max_w x max_h."""
    aspect = yr / xr if xr > 0 else 1.0
    w, h = max_w, max_w * aspect
    if h > max_h:
        w, h = max_h / aspect, max_h
    return max(w, 4.0), max(h, 1.5)


def layer_count(depth: float, r: np.ndarray) -> int:
    """About four mean disc diameters per layer, 4..16 layers."""
    d = 2.0 * float(np.mean(r)) if len(r) else depth / 8
    return int(np.clip(round(depth / (4.0 * d)), 4, 16))


# the least a figure takes (PNG, measured 40-200 kB): checked against the free space and the
# file-size limit before it is drawn to disk
FIGURE_BYTES = 16 << 10


EXTRA_FORMATS = ("pdf", "svg")  # what a figure may also be written as, beside its PNG
_ALSO: ContextVar[tuple[str, ...]] = ContextVar("figure_formats", default=())


@contextmanager
def also_saved_as(formats: tuple[str, ...]) -> Iterator[None]:
    """Within: every figure saved is also written in these formats (EXTRA_FORMATS), beside the
    PNG under the same name."""
    token = _ALSO.set(tuple(formats))
    try:
        yield
    finally:
        _ALSO.reset(token)


def save_figure(fig: Figure, path: Path) -> Path:
    # under a temporary name, renamed when complete: a kill never leaves a torn figure that a
    # resume would take for a finished one
    write_replacing(path, lambda tmp: fig.savefig(tmp, dpi=DPI, format="png"), need=FIGURE_BYTES)
    for fmt in _ALSO.get():

        def write(tmp: Any, fmt: str = fmt) -> None:
            fig.savefig(tmp, dpi=DPI, format=fmt)

        write_replacing(path.with_suffix(f".{fmt}"), write, need=FIGURE_BYTES)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path
