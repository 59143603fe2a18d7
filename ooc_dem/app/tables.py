"""The text table of a wheel run: ``print_table(summary)`` formats ``summary.json`` like
the paper's Table 3 (Nakashima 2008), with the paper's values beside a ``paper2008`` run."""

from __future__ import annotations

import math
from typing import Any

from .runfiles import summary_field, summary_value, summary_window


# Nakashima (2008) Table 3, without DDM, whole 45 s of travel
PAPER_TABLE3 = {
    "slip": 0.736,
    "net_traction": 9.968,
    "gross_traction": 12.697,
    "motion_resistance": 12.697 - 9.968,
    "wall_time_s": 6844.0,
}


def print_table(summary: dict[str, Any], reference: dict[str, float] | None = None) -> str:
    """Table-3-style text table of a run's ``summary.json`` (returned, not printed).

    Columns: the whole-travel and the steady window, each labelled with its
    bounds (s of travel). For the ``paper2008`` scenario a column with the
    paper's values (without DDM) is added unless ``reference`` is given; pass
    ``reference={}`` to suppress it.
    """
    cols = ("whole_travel", "steady")
    heads = []
    for c in cols:
        w = summary_window(summary, "slip", c) or summary_window(summary, "net_traction", c)
        label = "whole travel" if c == "whole_travel" else "steady"
        heads.append(f"{label} {w[0]:g}–{w[1]:g} s" if w else label)
    if reference is None:
        reference = PAPER_TABLE3 if summary.get("scenario") == "paper2008" else {}
    if reference:
        heads.append("paper 2008 (no DDM)")

    def fmt(v: float | None, scale: float = 1.0, digits: int = 3) -> str:
        if v is None:
            return "—"
        try:
            v = float(v) * scale
        except (TypeError, ValueError):
            return "—"
        return "nan" if not math.isfinite(v) else f"{v:.{digits}f}"

    def cell(key: str, col: str, scale: float, digits: int) -> str:
        """The value, and ± the 95 % half-width of the steady mean when the summary has it."""
        text = fmt(summary_value(summary, key, col), scale, digits)
        ci = summary_field(summary, key, col, "ci95")
        if col == "steady" and text not in ("—", "nan") and isinstance(ci, (int, float)):
            text += f" ± {fmt(ci, scale, digits)}"
        return text

    rows = []
    spec = (
        ("wheel slip (-)", "slip", 1.0, 3),
        ("net traction (N)", "net_traction", 1.0, 3),
        ("gross traction (N)", "gross_traction", 1.0, 3),
        ("motion resistance (N)", "motion_resistance", 1.0, 3),
        ("torque (N m)", "torque", 1.0, 4),
        ("DP/W (-)", "dp_w", 1.0, 4),
    )
    for label, key, scale, digits in spec:
        if key == "dp_w" and "dp_w" not in summary:
            continue  # a run made before DP/W was reported
        row = [label] + [cell(key, c, scale, digits) for c in cols]
        if reference:
            row.append(fmt(reference.get(key), 1.0, digits))
        rows.append(row)
    static = summary_value(summary, "sinkage", "static")
    row = ["static sinkage (mm)", fmt(static, 1e3, 1), ""]
    if reference:
        row.append("—")
    rows.append(row)
    row = ["travelling sinkage (mm)"] + [cell("sinkage", c, 1e3, 1) for c in cols]
    if reference:
        row.append("—")
    rows.append(row)
    if summary.get("wall_time_s") is not None:
        row = ["wall time (s)", fmt(summary["wall_time_s"], 1.0, 1), ""]
        if reference:
            row.append(fmt(reference.get("wall_time_s"), 1.0, 0))
        rows.append(row)

    header = ["quantity"] + heads
    widths = [max(len(r[k]) for r in rows + [header]) for k in range(len(header))]

    def line(r: list[str]) -> str:
        return "  ".join([r[0].ljust(widths[0])] + [r[k].rjust(widths[k]) for k in range(1, len(r))])

    name = summary.get("scenario", "")
    extra = ", ".join(str(summary[k]) for k in ("mode", "backend") if summary.get(k))
    title = f"Wheel performance — {name}" + (f" ({extra})" if extra else "")
    out = [title, line(header), "  ".join("-" * w for w in widths)] + [line(r) for r in rows]
    notes = [
        "windows in s of travel (0 = end of the wheel's settling); motion resistance = gross − net; "
        "DP/W = net traction / wheel load"
    ]
    blocks = summary_field(summary, "net_traction", "steady", "blocks")
    if isinstance(blocks, int):
        passages = summary_field(summary, "net_traction", "steady", "passages")
        what = f"{blocks} lug passages" if passages is not None else f"{blocks} blocks"
        used = summary_field(summary, "net_traction", "steady", "stats_window_s")
        where = f", t = {used[0]:.4g}–{used[1]:.4g} s" if isinstance(used, list) and len(used) == 2 else ""
        notes.append(
            f"± : 95 % confidence half-width of the steady mean from {what}{where} "
            "(Student t over the blocks' means; docs/reference/statistics.md)"
            if blocks >= 2
            else f"no confidence interval: the steady window holds {what} (at least 2 are needed)"
        )
    flag = summary_field(summary, "net_traction", "steady", "flag")
    if isinstance(flag, str):
        notes.append(f"steady window flagged: {flag} (the spread is not reliable; travel longer)")
    sw = summary_window(summary, "sinkage", "static")
    if static is not None:
        notes.append(
            "static sinkage: mean at the end of settling (ω = 0)" + (f", t = {sw[0]:g}–{sw[1]:g} s" if sw else "")
        )
    if reference:
        notes.append("paper 2008: Nakashima, CIGR Ejournal PM 08 006, Table 3 (whole 45 s, 2008 Mac Pro)")
    return "\n".join(out + [""] + notes)
