"""Reading a run directory's files, validated: they are untrusted input (a run directory may
come from anyone), so each is checked against what ooc-dem writes and refused in one line
(``RunFileError``) otherwise.

* ``run_file(out, name)``: a regular file inside the run directory (no symlink out of it);
* ``read_summary`` (``summary.json``), ``read_series`` (``series.csv``), ``read_initial`` and
  ``read_initial_z`` (``initial.npz``), ``read_run_scenario`` (``scenario.toml``),
  ``read_bed_info`` (``bed.json``);
* ``read_final`` / ``read_final_particles``: the last committed epoch of the run's store.
"""

from __future__ import annotations

import json
import math
import os
import stat
import warnings
from pathlib import Path
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Literal, TypeAlias, overload

import numpy as np
from numpy.typing import NDArray

from ..errors import OocDemError
from ..physics.layout import AX_X, AX_Y

if TYPE_CHECKING:
    from ..model.scenario import Scenario
    from ..model.state import Particles


class RunFileError(OocDemError, ValueError):
    """A file of a run directory is missing, unreadable or not what ooc-dem writes (one line)."""


MAX_SUMMARY_BYTES = 16 << 20  # summary.json is a few kB; anything this big is not ours
MAX_SCENARIO_BYTES = 1 << 20
MAX_BED_INFO_BYTES = 64 << 10  # bed.json is under 1 kB
MAX_HEADER_CHARS = 4096
SERIES_NEEDED = ("slip", "net_traction", "gross_traction", "torque", "sinkage")  # the series figure's
INITIAL_ARRAYS = ("id", "x", "y", "r", "surface")

# an initial bed as read_initial gives it: id, x, y, r and the surface height
InitialBed: TypeAlias = tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float]
# a final state as read_final gives it: id, x, y, r and the wheel state
FinalState: TypeAlias = tuple[
    NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]
]


@overload
def run_file(out: str | os.PathLike[str], name: str, required: Literal[True]) -> Path: ...


@overload
def run_file(out: str | os.PathLike[str], name: str, required: bool = False) -> Path | None: ...


def run_file(out: str | os.PathLike[str], name: str, required: bool = False) -> Path | None:
    """``out/name`` if it is a regular file inside ``out`` (a symlink may not lead outside the run
    directory, and a FIFO or device is never opened); None if absent and not required."""
    out = Path(out)
    f = out / name
    if not os.path.lexists(f):
        if required:
            raise RunFileError(f"{out}: no {name} (not a finished ooc-dem run)")
        return None
    try:
        real = f.resolve(strict=True)
        inside = real.is_relative_to(out.resolve(strict=True))
        regular = stat.S_ISREG(os.stat(real).st_mode)
    except (OSError, RuntimeError) as e:  # dangling or looping symlink
        raise RunFileError(f"{f}: unreadable ({one_line(e)})") from None
    if not inside:
        raise RunFileError(f"{f}: leads outside the run directory (refused)")
    if not regular:
        raise RunFileError(f"{f}: not a regular file")
    return f


def one_line(e: object) -> str:
    """An error's text on one line, at most 160 characters."""
    text = " ".join(str(e).split()) or type(e).__name__
    return text if len(text) <= 160 else text[:157] + "..."


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


# what Simulation.finish writes; `report` and `compare` need all of it
SUMMARY_FIELDS: dict[str, type | Callable[[object], bool]] = {
    "scenario": str,
    "scenario_hash": str,
    "mode": str,
    "backend": str,
    "steps": int,
    "simulated_time_s": _is_number,
    "wall_time_s": _is_number,
    "n_discs": int,
    "engine": dict,
    "state_hash": str,
}
WHEEL_QUANTITIES = (
    "slip",
    "net_traction",
    "gross_traction",
    "torque",
    "vertical_force",
    "travel_distance",
    "sinkage",
    "motion_resistance",
)
# in a wheel run's summary when present (runs made before they were written lack them)
OPTIONAL_QUANTITIES = ("dp_w",)
# a steady entry's spread (run_stats.py): numbers or null, counts, windows and a flag
SPREAD_NUMBERS = ("mean", "std", "ci95", "block_s")
SPREAD_COUNTS = ("blocks", "passages")
WINDOWS = ("whole_travel", "steady", "static")


def _type_ok(v: object, want: type | Callable[[object], bool]) -> bool:
    if want is int:
        return isinstance(v, int) and not isinstance(v, bool)
    if isinstance(want, type):
        return isinstance(v, want)
    return want(v)


def validate_summary(summary: object, f: str | os.PathLike[str], complete: bool = True) -> dict[str, Any]:
    """``summary`` as Simulation.finish writes it, or RunFileError naming ``f`` and the key.
    ``complete``: every key finish writes must be there (not only well-typed when present)."""
    if not isinstance(summary, dict):
        raise RunFileError(f"{f}: not a JSON object")
    for key, want in SUMMARY_FIELDS.items():
        if key not in summary:
            if complete:
                raise RunFileError(f"{f}: missing key {key!r}")
            continue
        if not _type_ok(summary[key], want):
            raise RunFileError(f"{f}: {key!r} has the wrong type ({type(summary[key]).__name__})")
    engine = summary.get("engine", {})
    for key in ("domains", "block"):
        if key in engine and not _type_ok(engine[key], int):
            raise RunFileError(f"{f}: 'engine.{key}' must be an integer")
    wheel = "slip" in summary
    for q in WHEEL_QUANTITIES + OPTIONAL_QUANTITIES:
        if q not in summary:
            if wheel and complete and q not in OPTIONAL_QUANTITIES:
                raise RunFileError(f"{f}: missing key {q!r} (a wheel run's summary has it)")
            continue
        entry = summary[q]
        if not isinstance(entry, dict):
            raise RunFileError(f"{f}: {q!r} must be an object")
        for win in WINDOWS:
            if win not in entry:
                continue
            w = entry[win]
            where = f"{q}.{win}"
            if not isinstance(w, dict):
                raise RunFileError(f"{f}: {where!r} must be an object")
            if w.get("value") is not None and not _is_number(w["value"]):
                raise RunFileError(f"{f}: '{where}.value' must be a number or null")
            for key in ("window_s", "stats_window_s"):
                ws = w.get(key)
                if ws is not None and not (isinstance(ws, list) and len(ws) == 2 and all(map(_is_number, ws))):
                    raise RunFileError(f"{f}: '{where}.{key}' must be [start, end] in s or null")
            for key in SPREAD_NUMBERS:
                if w.get(key) is not None and not _is_number(w[key]):
                    raise RunFileError(f"{f}: '{where}.{key}' must be a number or null")
            for key in SPREAD_COUNTS:
                if w.get(key) is not None and not _type_ok(w[key], int):
                    raise RunFileError(f"{f}: '{where}.{key}' must be an integer or null")
            if w.get("flag") is not None and not (isinstance(w["flag"], str) and len(w["flag"]) <= 200):
                raise RunFileError(f"{f}: '{where}.flag' must be a short string or null")
    if "bed" in summary:
        validate_bed_info(summary["bed"], f, "'bed'")
    surf = summary.get("surface_height")
    if surf is not None and not (isinstance(surf, dict) and (surf.get("value") is None or _is_number(surf["value"]))):
        raise RunFileError(f"{f}: 'surface_height' must be an object with a numeric value")
    return summary


def validate_bed_info(info: Any, f: str | os.PathLike[str], what: str = "bed.json") -> dict[str, Any]:
    """``info`` as bed.json holds it (bed.bed_info: one level of numbers, strings and null,
    and the grading's numbers), or RunFileError naming ``f``."""
    if not isinstance(info, dict) or len(info) > 64:
        raise RunFileError(f"{f}: {what} must be an object of at most 64 keys")
    for key, v in info.items():
        ok = (
            v is None
            or (_is_number(v) and math.isfinite(v))
            or (isinstance(v, str) and len(v) <= 200)
            or (
                key == "grading"
                and isinstance(v, dict)
                and len(v) <= 16
                and all(_is_number(x) and math.isfinite(x) for x in v.values())
            )
        )
        if not ok:
            raise RunFileError(f"{f}: {what}: {str(key)[:40]!r} must be a finite number, a short string or null")
    return info


def read_bed_info(out: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The run's ``bed.json`` (the bed's report, summary.json's ``bed``), validated; None if
    absent (a run made before beds reported themselves)."""
    f = run_file(out, "bed.json")
    if f is None:
        return None
    if f.stat().st_size > MAX_BED_INFO_BYTES:
        raise RunFileError(f"{f}: {f.stat().st_size} bytes, too large for a bed report (at most {MAX_BED_INFO_BYTES})")
    try:
        info = json.loads(f.read_bytes())
    except (ValueError, RecursionError) as e:
        raise RunFileError(f"{f}: not valid JSON ({one_line(e)})") from None
    return validate_bed_info(info, f)


@overload
def read_summary(out: str | os.PathLike[str], complete: Literal[True] = ...) -> dict[str, Any]: ...


@overload
def read_summary(out: str | os.PathLike[str], complete: bool) -> dict[str, Any] | None: ...


def read_summary(out: str | os.PathLike[str], complete: bool = True) -> dict[str, Any] | None:
    """The run's ``summary.json``, validated (None if absent and not ``complete``)."""
    f = run_file(out, "summary.json", required=complete)
    if f is None:
        return None
    if f.stat().st_size > MAX_SUMMARY_BYTES:
        raise RunFileError(f"{f}: {f.stat().st_size} bytes, too large for a summary (at most {MAX_SUMMARY_BYTES})")
    try:
        summary = json.loads(f.read_bytes())
    except (ValueError, RecursionError) as e:  # bad JSON or UTF-8, nesting, digit limit
        raise RunFileError(f"{f}: not valid JSON ({one_line(e)})") from None
    return validate_summary(summary, f, complete)


def read_csv(path: str | os.PathLike[str], needed: Sequence[str] = ()) -> dict[str, NDArray[np.float64]]:
    """Columns of a comma-separated file with a one-line header; ``name [unit]`` -> ``name``."""
    path = Path(path)
    try:
        with open(path, encoding="utf-8") as f:
            header = f.readline(MAX_HEADER_CHARS).strip()
        names = [h.strip().split(" [")[0].strip() for h in header.split(",")]
        missing = [n for n in needed if n not in names]
        if not header or missing:
            raise RunFileError(
                f"{path}: header has no column {(missing or needed or ['(any)'])[0]!r} "
                f"(not a series written by ooc-dem)"
            )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data": a header-only file is valid
            data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, encoding="utf-8")
    except RunFileError:
        raise
    except (ValueError, UnicodeDecodeError, OSError) as e:
        raise RunFileError(f"{path}: not a numeric CSV table ({one_line(e)})") from None
    if data.size == 0:
        data = np.zeros((0, len(names)))
    if data.shape[1] != len(names):
        raise RunFileError(f"{path}: header has {len(names)} columns, rows have {data.shape[1]}")
    return {n: data[:, k] for k, n in enumerate(names)}


def read_series(path: str | os.PathLike[str]) -> dict[str, NDArray[np.float64]]:
    """``series.csv`` as a dict of column arrays keyed by name without unit (``t_travel``, ``slip``...)."""
    cols = read_csv(path, SERIES_NEEDED)
    if "t_travel" not in cols and "t" not in cols:
        raise RunFileError(f"{path}: header has no column 't_travel' or 't'")
    return cols


# |coordinate|, radius and surface height [m] an initial bed may hold when no scenario gives
# the bin (far beyond any bed; it keeps the figures' extents finite)
MAX_INITIAL_COORD = 1e6


def read_initial(path: str | os.PathLike[str], n: int | None = None, sc: Scenario | None = None) -> InitialBed:
    """``initial.npz`` (id, x, y, r, surface), checked: never unpickled, shapes and dtypes as
    written, sizes read from its headers before anything is allocated (``n``: the run's disc
    count when known), distinct ids, finite positions, radii > 0 and a surface above the
    floor, within the scenario's bin (``sc``) or MAX_INITIAL_COORD."""
    from ..storage.npzfile import read_npz_members

    want = {"id": ((), "iu"), "x": ((), "iuf"), "y": ((), "iuf"), "r": ((), "iuf"), "surface": (None, "iuf")}
    a = read_npz_members(path, want, n, RunFileError)
    if len(a["id"]) != len(a["x"]) or len(a["y"]) != len(a["x"]) or len(a["r"]) != len(a["x"]):
        raise RunFileError(f"{path}: 'id', 'x', 'y' and 'r' differ in length")
    iid = a["id"].astype(np.int64)
    x, y, r = (a[k].astype(np.float64) for k in ("x", "y", "r"))
    surface = float(a["surface"])
    if len(np.unique(iid)) != len(iid):
        raise RunFileError(f"{path}: 'id' holds a disc id twice")
    reach = MAX_INITIAL_COORD if sc is None else 10.0 * max(sc.bin.length, sc.bin.height)
    for k, v in (("x", x), ("y", y)):
        if not (np.isfinite(v).all() and (np.abs(v) <= reach).all()):
            raise RunFileError(f"{path}: {k!r} holds values that are not finite or beyond {reach:g} m")
    if not (np.isfinite(r).all() and (r > 0).all() and (r <= reach).all()):
        raise RunFileError(f"{path}: 'r' must be radii in (0, {reach:g}] m")
    if not 0.0 < surface <= reach:
        raise RunFileError(f"{path}: 'surface' = {surface!r} is not a height in (0, {reach:g}] m")
    return iid, x, y, r, surface


def summary_window(summary: dict[str, Any] | None, key: str, name: str) -> tuple[float, float] | None:
    """(start, end) in s of window ``name`` of quantity ``key`` of a summary (None if absent)."""
    if summary is None:
        return None
    try:
        w = summary[key][name]["window_s"]
        return (float(w[0]), float(w[1])) if w is not None else None
    except (KeyError, TypeError, IndexError):
        return None


def read_run_scenario(out: str | os.PathLike[str]) -> Scenario | None:
    """The run's ``scenario.toml``, checked (None if absent)."""
    f = run_file(out, "scenario.toml")
    if f is None:
        return None
    from ..model.scenario import ScenarioError, scenario_from_toml

    if f.stat().st_size > MAX_SCENARIO_BYTES:
        raise RunFileError(f"{f}: too large for a scenario")
    try:
        return scenario_from_toml(f.read_text(encoding="utf-8"))
    except (ScenarioError, UnicodeDecodeError) as e:
        raise RunFileError(f"{f}: not a valid scenario ({one_line(e)})") from None


def has_store(out: Path) -> bool:
    """A store to read the final state from: on disk, or a memory store of this process."""
    if os.path.lexists(out / "MANIFEST.json"):
        return True
    from ooc_dem.storage import StoreError, open_store

    try:
        open_store(out, repair=False).close()
    except StoreError:
        return False
    return True


def read_final(out: str | os.PathLike[str]) -> FinalState:
    """(id, x, y, r, wheel_state) of the last committed epoch of the run's store."""
    p, ws = read_final_particles(out)
    return p.id.copy(), p.pos[:, AX_X].copy(), p.pos[:, AX_Y].copy(), p.r.copy(), ws


def read_final_particles(out: str | os.PathLike[str]) -> tuple[Particles, NDArray[np.float64]]:
    """(Particles, wheel_state) of the last committed epoch of the run's store."""
    from ooc_dem.storage import open_store
    from ..model.checkpoint import read_epoch_particles

    store = open_store(out, repair=False)  # read-only: the run drawing it may hold the write lock
    try:
        p, arrays, _ = read_epoch_particles(store, str(out))
        ws = np.asarray(arrays["wheel_state"], dtype=np.float64).copy()
    finally:
        store.close()
    return p, ws


def summary_value(summary: dict[str, Any] | None, key: str, name: str) -> float | None:
    """The value of quantity ``key`` over window ``name`` of a summary (None if absent)."""
    if summary is None:
        return None
    try:
        v = summary[key][name]["value"]
        return None if v is None else float(v)
    except (KeyError, TypeError, ValueError):
        return None


def summary_field(summary: dict[str, Any] | None, key: str, name: str, field: str) -> Any:
    """Field ``field`` (``ci95``, ``blocks``, ``flag``...) of quantity ``key`` over window
    ``name`` of a summary (None if absent)."""
    try:
        return None if summary is None else summary[key][name].get(field)
    except (KeyError, TypeError, AttributeError):
        return None


def read_initial_z(path: str | os.PathLike[str], n: int) -> NDArray[np.float64] | None:
    """The initial bed's z (3D runs write it to initial.npz), checked; None without it."""
    from ..storage.npzfile import npz_member_names, read_npz_members

    if "z" not in npz_member_names(path, RunFileError):
        return None
    a = read_npz_members(path, {"z": ((), "iuf")}, n, RunFileError)["z"]
    if not np.isfinite(a).all():
        raise RunFileError(f"{path}: 'z' must be a 1-D finite numeric array of {n} entries")
    return a.astype(np.float64)
