"""`ooc-dem compare A B`: Table-3-style comparison of two runs and their final states."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from .runfiles import RunFileError, read_summary


def _summary(run: str | os.PathLike[str]) -> dict[str, Any]:
    """A finished run's summary, validated (hostile files: one-line errors)."""
    s = read_summary(Path(run))
    if s is None:  # read_summary raises for a missing summary of a finished run; never None
        raise RunFileError(f"{run}: no summary.json (not a finished ooc-dem run)")
    return s


def compare_runs(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> str:
    sa, sb = _summary(a), _summary(b)

    def val(s: dict[str, Any], key: str, win: str = "whole_travel") -> Any:
        v = s.get(key)
        return v.get(win, {}).get("value") if isinstance(v, dict) else v

    def label(s: dict[str, Any]) -> str:
        e = s.get("engine", {})
        extra = f", D={e['domains']}, K={e.get('block', '?')}" if "domains" in e else ""
        return f"{s.get('mode')}{extra}"

    rows = [
        ("wheel slip (-)", "slip", "{:.6f}"),
        ("net traction (N)", "net_traction", "{:.6f}"),
        ("gross traction (N)", "gross_traction", "{:.6f}"),
        ("sinkage (mm)", "sinkage", "{:.4f}"),
    ]
    out = [f"{'':24s} {'A: ' + label(sa):>28s} {'B: ' + label(sb):>28s}"]
    if "slip" in sa and "slip" in sb:
        for win in ("whole_travel", "steady"):
            w = sa["slip"].get(win, {}).get("window_s")
            out.append(f"-- {win.replace('_', ' ')} window {w} s")
            for name, key, fmt in rows:
                va, vb = val(sa, key, win), val(sb, key, win)
                scale = 1e3 if key == "sinkage" else 1.0
                fa = fmt.format(va * scale) if va is not None else "—"
                fb = fmt.format(vb * scale) if vb is not None else "—"
                out.append(f"{name:24s} {fa:>28s} {fb:>28s}")
    out.append(
        f"{'elapsed time (s)':24s} {sa.get('wall_time_s', float('nan')):>28.1f} "
        f"{sb.get('wall_time_s', float('nan')):>28.1f}"
    )
    out.append(f"{'steps':24s} {sa['steps']:>28} {sb['steps']:>28}")
    ha, hb = sa.get("state_hash"), sb.get("state_hash")
    same = ha is not None and ha == hb
    # the state hash is the canonical multiset hash (statehash, "mset-v2:<hex>")
    out.append(
        f"final states: {'BIT-IDENTICAL' if same else 'DIFFERENT'} (state hash "
        f"{ha[:24] if ha else '?'}… vs {hb[:24] if hb else '?'}…)"
    )
    return "\n".join(out)
