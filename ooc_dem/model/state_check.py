"""A stored state refused before it is stepped, hashed or exported (``StateError``).

A store is untrusted input: an epoch whose checksums pass may still have been edited
consistently. ``validate_record`` checks one domain's record (names, dtypes, shapes, finite
values, positive masses, materials, unique ids, the contact history's CSR and its partner
order; with a scenario's ``StateBounds``, radii, masses, positions and speeds in range);
``checked_groups`` / ``validate_epoch`` check an epoch group by group, its globals and its
ids unique across groups (``check_unique_ids``, in bounded memory). The records themselves
and the epochs that hold them are checkpoint.py's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import OocDemError
from ..physics.layout import AX_X, WS_SIZE
from .decomposition import x_summary
from .schema import show
from .state import DISC_FIELDS, HIST_FIELDS, default_hist_cap, record_fields


class StateError(OocDemError, ValueError):
    """A stored state is not one this engine could have written (one-line message).

    A store is untrusted input: an epoch whose checksums pass may still have been
    edited consistently (NaN positions, a history count beyond capacity, duplicated
    disc ids). Such a state is refused before it is stepped, hashed or exported.
    """


# fields that must hold finite numbers; radii, masses and inertias must be > 0 too
_FINITE_FIELDS = ("pos", "vel", "spin", "r", "mass", "inertia", "hist_s", "hist_m")
_POSITIVE_FIELDS = ("r", "mass", "inertia")


def material_count(dim: int) -> int:
    """The materials a disc may name: the rows of the contact table (``Model.cp``)."""
    if dim == 3:
        from ..physics.d3.layout import N_TYPES

        return N_TYPES
    from ..physics.layout import N_TYPES

    return N_TYPES


# a state read for a scenario (StateBounds): radii within this factor of the scenario's
# range, masses and inertias within MASS_SLACK of those of a disc of that radius, and
# positions within BOX_MARGIN bin extents of the bin. Legitimate states sit at factor 1
# (beds are made of exactly these discs); the slack only keeps older or hand-made beds.
RADIUS_SLACK = 2.0
MASS_SLACK = 10.0
BOX_MARGIN = 10.0


@dataclass(frozen=True)
class StateBounds:
    """What a scenario says of the discs of any state of its runs, beyond the layout: the
    disc count (``soil.n``), radii, masses and inertias in sane ratios to the soil's,
    positions within a generous box around the bin, and speeds (and spins at the rim) of
    at most r_max per time step: past that a step's contact detection is meaningless, and
    values far beyond it (1e300) overflow the neighbour grid's arithmetic."""

    n_discs: int
    dt: float
    r_min: float
    r_max: float
    density: float
    thickness: float
    box_lo: tuple
    box_hi: tuple


def state_bounds(sc) -> StateBounds:
    """The StateBounds of a scenario's states."""
    extent = (sc.bin.length, sc.bin.height) + ((sc.bin.width,) if sc.dim == 3 else ())
    margin = BOX_MARGIN * max(extent)
    return StateBounds(
        n_discs=sc.soil.n,
        dt=sc.physics.dt,
        r_min=sc.soil.r_min,
        r_max=sc.soil.r_max,
        density=sc.soil.density,
        thickness=sc.physics.thickness,
        box_lo=tuple(-margin for _ in extent),
        box_hi=tuple(e + margin for e in extent),
    )


def _check_bounds(rec: dict, where: str, dim: int, b: StateBounds) -> None:
    """validate_record's scenario part (``StateBounds``): one line naming the array."""
    r = rec["r"]
    if not len(r):
        return
    if r.min() < b.r_min / RADIUS_SLACK or r.max() > b.r_max * RADIUS_SLACK:
        raise StateError(
            f"{where}: array 'r' holds radii outside [{b.r_min / RADIUS_SLACK:g}, "
            f"{b.r_max * RADIUS_SLACK:g}] (the scenario's soil.r_min = {b.r_min:g}, "
            f"r_max = {b.r_max:g})"
        )
    if dim == 3:
        nominal = b.density * (4.0 / 3.0) * math.pi * r**3
    else:
        nominal = b.density * math.pi * r * r * b.thickness
    ratio = rec["mass"] / nominal
    if ratio.min() < 1.0 / MASS_SLACK or ratio.max() > MASS_SLACK:
        raise StateError(
            f"{where}: array 'mass' holds masses beyond {MASS_SLACK:g} times those of "
            f"discs of that radius and soil.density = {b.density:g}"
        )
    ratio = rec["inertia"] / (rec["mass"] * r * r)
    if ratio.min() < 0.4 / MASS_SLACK or ratio.max() > 0.5 * MASS_SLACK:
        raise StateError(
            f"{where}: array 'inertia' holds inertias beyond {MASS_SLACK:g} times "
            f"those of discs of that mass and radius"
        )
    pos = rec["pos"]
    lo, hi = np.asarray(b.box_lo), np.asarray(b.box_hi)
    if (pos.min(axis=0) < lo).any() or (pos.max(axis=0) > hi).any():
        raise StateError(
            f"{where}: array 'pos' holds positions far outside the bin (beyond {BOX_MARGIN:g} bin extents)"
        )
    reach = (b.r_max / b.dt) ** 2  # squared: no root, and 1e300 squares to inf, still refused
    if np.einsum("ij,ij->i", rec["vel"], rec["vel"]).max() > reach:
        raise StateError(
            f"{where}: array 'vel' holds speeds above soil.r_max / physics.dt = "
            f"{b.r_max / b.dt:g} m/s (a disc would cross its radius in one step)"
        )
    spin = rec["spin"]
    if (np.einsum("ij,ij->i", spin, spin) * (r * r)).max() > reach:
        raise StateError(
            f"{where}: array 'spin' holds spins whose rim speed is above "
            f"soil.r_max / physics.dt = {b.r_max / b.dt:g} m/s"
        )


def validate_record(
    rec: dict, where: str, dim: int | None = 2, hist_cap: int | None = None, bounds: StateBounds | None = None
) -> None:
    """Refuse a domain record that this engine could not have written (StateError).

    Checks names, dtypes and shapes of every field (``state.record_fields(dim)``: pos must
    be (n, dim) etc.; dim None: pos's own width, 2 or 3), finite kinematics and springs,
    positive radii/masses/inertias, non-negative ids, materials in [0, materials) (the
    contact table's rows), ids unique within the record, history counts within
    [0, hist_cap] that add up to the CSR entries, and each disc's partners in strictly
    ascending id order (the sum order of the determinism contract) and never itself; with
    `bounds`, the scenario's (``StateBounds``).
    """
    if dim is None:
        pos = rec.get("pos")
        dim = pos.shape[1] if pos is not None and pos.ndim == 2 and pos.shape[1] in (2, 3) else 2
    spec = record_fields(dim)
    for name, (dt, tail) in spec.items():
        a = rec.get(name)
        if a is None:
            raise StateError(f"{where}: array {name!r} missing")
        if a.ndim != 1 + len(tail) or a.shape[1:] != tail or a.dtype != dt:
            want = "(rows" + "".join(f", {k}" for k in tail) + ")"
            raise StateError(
                f"{where}: array {name!r} is {a.dtype} with shape {a.shape}, expected {want} {dt} ({dim}D)"
            )
    n = len(rec["id"])
    for name in DISC_FIELDS:
        if len(rec[name]) != n:
            raise StateError(f"{where}: array {name!r} has {len(rec[name])} rows, 'id' has {n}")
    for name in _FINITE_FIELDS:
        if not np.isfinite(rec[name]).all():
            raise StateError(f"{where}: array {name!r} holds non-finite values")
    for name in _POSITIVE_FIELDS:
        if n and not (rec[name] > 0).all():
            raise StateError(f"{where}: array {name!r} holds values <= 0")
    for name in ("id", "mat"):
        if n and rec[name].min() < 0:
            raise StateError(f"{where}: array {name!r} holds negative values")
    if n and rec["mat"].max() >= material_count(dim):
        raise StateError(
            f"{where}: array 'mat' holds {int(rec['mat'].max())}, beyond the "
            f"{material_count(dim)} materials of the contact table"
        )
    check_unique_sorted(np.sort(rec["id"]), where)
    hist_n = rec["hist_n"]
    hist_cap = default_hist_cap(dim) if hist_cap is None else hist_cap
    if n and (hist_n.min() < 0 or hist_n.max() > hist_cap):
        raise StateError(f"{where}: hist_n outside [0, {hist_cap}] (contact history capacity)")
    total = int(hist_n.sum(dtype=np.int64))
    for name in HIST_FIELDS:
        if len(rec[name]) != total:
            raise StateError(f"{where}: array {name!r} has {len(rec[name])} entries, hist_n adds up to {total}")
    owner = np.repeat(rec["id"], hist_n)
    partner = rec["hist_id"]
    if (partner == owner).any():
        raise StateError(f"{where}: a disc's contact history names the disc itself")
    same_disc = owner[1:] == owner[:-1]
    if (same_disc & (partner[1:] <= partner[:-1])).any():
        raise StateError(f"{where}: contact history not in strictly ascending partner-id order")
    if bounds is not None:
        # a hostile value may overflow a ratio: inf is refused by the comparison, not warned about
        with np.errstate(all="ignore"):
            _check_bounds(rec, where, dim, bounds)


def validate_globals(arrays: dict, attrs: dict, where: str, step: int | None = None) -> None:
    """Refuse an epoch's globals group that lacks what a resume needs (StateError); with
    `step` (the manifest's), one whose own step differs."""
    if not isinstance(attrs, dict):
        raise StateError(f"{where}: globals attributes are not an object")
    ws = arrays.get("wheel_state")
    if ws is None:
        raise StateError(f"{where}: globals hold no wheel_state")
    if ws.shape != (WS_SIZE,) or ws.dtype.kind != "f" or not np.isfinite(ws).all():
        raise StateError(f"{where}: wheel_state must be {WS_SIZE} finite floats, got {ws.dtype} {ws.shape}")
    expected, step = step, attrs.get("step")
    if type(step) is not int or step < 0:
        raise StateError(f"{where}: globals attribute 'step' = {show(step)}: must be an integer >= 0")
    if expected is not None and step != expected:
        raise StateError(
            f"{where}: globals attribute 'step' = {step}, the manifest says the epoch holds step {expected}"
        )
    for key in ("time", "surface", "wall_time"):
        v = attrs.get(key, 0.0)
        if type(v) not in (int, float) or not math.isfinite(v):
            raise StateError(f"{where}: globals attribute {key!r} = {show(v)}: must be a finite number")
    red = attrs.get("redecompositions", [])
    if not isinstance(red, list):
        raise StateError(f"{where}: globals attribute 'redecompositions' must be a list")


def validate_epoch(
    reader, where: str, dim: int | None = 2, hist_cap: int | None = None, bounds: StateBounds | None = None
) -> None:
    """Refuse an epoch that this engine could not have written (StateError), domain by domain:
    the one validation of every reader of an epoch (resume, ``hash_epoch``, export, the
    API's ``state()``, the figures), ``checked_groups`` consumed.

    Held in RAM: one domain at a time (and the bounded id check).
    """
    for _ in checked_groups(reader, where, dim, hist_cap, bounds):
        pass


def checked_groups(
    reader, where: str, dim: int | None = 2, hist_cap: int | None = None, bounds: StateBounds | None = None
):
    """Yield (d, record) of every domain group of an epoch, each validated, after the
    globals (``validate_globals``, their step the manifest's); when all are yielded, ids
    are checked unique across domains (``check_unique_ids``) and, with `bounds`, the disc
    count against the scenario's. A reader that streams the epoch (``hash_epoch``) reads
    it once; a StateError may come after the last group, so results are used only once
    the generator is exhausted.

    Every record passes ``validate_record`` and its stored attrs agree with it.
    """
    arrays, attrs = reader.read_globals()
    validate_globals(arrays, attrs, f"{where}: epoch {reader.step}", reader.step)
    n_discs = 0
    for d in reader.domains():
        at = f"{where}: epoch {reader.step} domain {d}"
        rec = reader.read_domain(d)
        validate_record(rec, at, dim, hist_cap, bounds)
        dattrs = reader.domain_attrs(d)
        if not isinstance(dattrs, dict):
            raise StateError(f"{at}: attributes are not an object")
        for key in ("xmin", "xmax"):  # every writer records them: the sweeps' reads depend on them
            v = dattrs.get(key)
            if not (type(v) is int or type(v) is float) or not math.isfinite(v):
                raise StateError(f"{at}: attribute {key!r} = {show(v)}: must be a finite number")
        if "n" in dattrs and dattrs["n"] != len(rec["id"]):
            raise StateError(f"{at}: attribute 'n' = {show(dattrs['n'])}, the domain holds {len(rec['id'])} discs")
        x = rec["pos"][:, AX_X]  # in any row order: halo reads filter their candidate rows by x
        if len(x) and (x.min() < dattrs["xmin"] or x.max() > dattrs["xmax"]):
            raise StateError(f"{at}: discs outside the domain's stored x range")
        summary = dattrs.get("x_summary")  # absent in stores written before groups kept x summaries
        if summary is not None:
            length = summary.get("length") if isinstance(summary, dict) else None
            if type(length) is not float or not math.isfinite(length) or length <= 0 or summary != x_summary(x, length):
                raise StateError(f"{at}: attribute 'x_summary' does not match the domain's discs")
        n_discs += len(rec["id"])
        del x
        yield d, rec
        del rec
    if bounds is not None and n_discs != bounds.n_discs:
        raise StateError(
            f"{where}: epoch {reader.step} holds {n_discs} discs, the scenario has soil.n = {bounds.n_discs}"
        )
    check_unique_ids(reader, f"{where}: epoch {reader.step}")


def check_unique_sorted(sorted_ids: np.ndarray, where: str) -> None:
    dup = np.flatnonzero(sorted_ids[1:] == sorted_ids[:-1])
    if len(dup):
        raise StateError(f"{where}: disc id {int(sorted_ids[dup[0]])} appears more than once")


# ids held at once by check_unique_ids when twice the largest group is fewer (2**16: 512 kB).
# Kept small so that the check stays under a slab's memory: at 2**22 (32 MB of ids, and as much
# again for their concatenation and sort) it was the peak of out-of-core runs past 4M discs,
# and it made their RSS rise with N up to there. Ids that follow x (tiled and streamed beds)
# are read about twice whatever the cap; ids scattered over every group cost one read of every
# group per range, N / cap of them.
ID_CHECK_CAP = 1 << 16


def _group_ids(reader, d, where: str) -> np.ndarray:
    ids = np.asarray(reader.read_domain(d, ["id"])["id"])
    if ids.ndim != 1 or ids.dtype.kind not in "iu":
        raise StateError(
            f"{where} domain {d}: array 'id' is {ids.dtype} with shape {ids.shape}, expected (rows,) integers"
        )
    return ids


def check_unique_ids(reader, where: str, cap: int | None = None) -> None:
    """Refuse an epoch whose disc ids repeat (within a group or across groups), without
    holding one id per disc of the whole bed.

    Pass 1 reads each group's ids (one group at a time), checks them unique within the
    group and keeps its id range. Then the id axis is cut into ranges expected to hold at
    most ``cap`` ids (default max(ID_CHECK_CAP, 2 x the largest group)); for each range the
    ids of the groups whose id range meets it are gathered (one group read at a time),
    sorted and checked. A range found to hold more than ``cap`` ids is halved and retried,
    so memory stays bounded by cap plus one group whatever the ids are (a range of one id
    holding two is a duplicate at once). Groups holding contiguous runs of ids (tiled beds:
    ids follow x) are read about twice; ids scattered across every group cost a read of
    every group per range (N / cap ranges).
    """
    ranges = []  # (group, lowest id, highest id, count)
    for d in reader.domains():
        ids = np.sort(_group_ids(reader, d, where))
        if len(ids):
            check_unique_sorted(ids, f"{where} domain {d}")
            ranges.append((d, int(ids[0]), int(ids[-1]), len(ids)))
        del ids
    if len(ranges) < 2:
        return
    largest = max(r[3] for r in ranges)
    cap = max(ID_CHECK_CAP if cap is None else cap, 2 * largest)
    total = sum(r[3] for r in ranges)
    lo, hi = min(r[1] for r in ranges), max(r[2] for r in ranges) + 1
    parts = -(-total // cap)
    width = -(-(hi - lo) // parts)
    todo = [(a, min(hi, a + width)) for a in range(lo, hi, width)][::-1]
    while todo:
        a, b = todo.pop()
        groups = [d for d, g_lo, g_hi, _ in ranges if g_lo < b and g_hi >= a]
        if len(groups) < 2:
            continue  # within one group: checked in pass 1
        held, count, halve = [], 0, False
        for d in groups:
            ids = _group_ids(reader, d, where)
            sel = ids[(ids >= a) & (ids < b)]
            del ids
            count += len(sel)
            if b - a == 1 and count > 1:
                raise StateError(f"{where}: disc id {a} appears more than once")
            if count > cap:
                halve = True
                break
            held.append(sel)
        if halve:
            mid = a + (b - a) // 2
            todo += [(mid, b), (a, mid)]
            continue
        check_unique_sorted(np.sort(np.concatenate(held)), where)
        del held
