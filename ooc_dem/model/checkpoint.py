"""State <-> store records, epochs as checkpoints, and the canonical state hash.

A domain's record (store format 2) is a dict of arrays: the per-disc fields ``id`` (n,),
``pos``/``vel`` (n, D), ``spin`` (n, R), ``r, mass, inertia, mat, hist_n`` (n,), plus the
contact history in CSR form (``hist_id`` (E,), ``hist_s`` (E, S), ``hist_m`` (E, M), the
used slots disc after disc, each disc's sorted by partner id; E = sum of hist_n).
Format-1 epochs (2D components as their own arrays) are read through ``V1Epoch``. Every
epoch is validated as it is read (state_check.py).
"""

from __future__ import annotations

from typing import Any, TypeAlias

import numpy as np

from . import statehash
from .schema import show
from .state import (
    DISC_FIELDS,
    FIELD_DTYPES,
    HIST_FIELDS,
    V1_ARRAYS,
    Particles,
    default_hist_cap,
    stack_v1,
    upgrade_v1,
)
from .state_check import (
    StateBounds,
    StateError,
    check_unique_sorted,
    checked_groups,
    state_bounds,
    validate_epoch,
    validate_record,
)


# the run format (run meta ``format_version``, = the store format): 2 = per-particle vectors
# (pos, vel (n, D), spin (n, R), hist_s (E, S), hist_m (E, M)); 1 = the 2D components as
# their own arrays (x, y, vx, vy, w, hist_ft, hist_mr), read through ``V1Epoch``
FORMAT_VERSION = 2
SUPPORTED_VERSIONS = (1, 2)


def csr_slots(base: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The flat positions of CSR entries laid out disc after disc: disc i's counts[i]
    entries are base[i], base[i] + 1, ... (counts as intp). With base = row * capacity
    these are slots of the (N, capacity) history arrays; with base = a CSR start, entries
    of a stored record."""
    first = np.cumsum(counts) - counts
    return np.repeat(base - first, counts) + np.arange(int(counts.sum()))


def particles_to_record(p: Particles, rows=None) -> dict[str, np.ndarray]:
    """The store record (format 2) of a state, or of its discs `rows` in that order: the
    disc fields as they are, the history fields as CSR (the used slots, disc after disc).
    With `rows`, each field is gathered once, straight into the record (no intermediate
    state of the selected discs)."""
    if rows is None:
        rec = {k: np.ascontiguousarray(getattr(p, k), FIELD_DTYPES[k]) for k in DISC_FIELDS}
        rows = np.arange(len(p), dtype=np.intp)
    else:
        rows = np.asarray(rows, np.intp)
        rec = {k: np.asarray(getattr(p, k)[rows], FIELD_DTYPES[k]) for k in DISC_FIELDS}
    slots = csr_slots(rows * p.hist_cap, rec["hist_n"].astype(np.intp))
    for k in HIST_FIELDS:
        a = getattr(p, k)
        rec[k] = np.asarray(a.reshape(a.shape[0] * a.shape[1], *a.shape[2:])[slots], FIELD_DTYPES[k])
    return rec


def record_to_particles(rec: dict[str, np.ndarray], hist_cap: int | None = None) -> Particles:
    """A state from a store record (format 2; a format-1 record is converted first)."""
    return records_to_particles([rec], hist_cap)


def records_to_particles(recs: list[dict[str, np.ndarray]], hist_cap: int | None = None, dim: int = 2) -> Particles:
    """One state from store records (format 2; format 1 converted first), one after the
    other: allocated once, each record copied straight into its rows (no state per
    record and no concatenation). `dim` gives the shape of an empty result only."""
    recs = [upgrade_v1(r) for r in recs]
    for rec in recs:
        pos = rec.get("pos")
        if pos is None or pos.ndim != 2 or pos.shape[1] not in (2, 3):
            raise StateError(f"pos: shape {None if pos is None else pos.shape}, expected (n, 2) or (n, 3)")
        if recs[0]["pos"].shape[1] != pos.shape[1]:
            raise StateError("records of different dimensions")
    dim = recs[0]["pos"].shape[1] if recs else dim
    hist_cap = default_hist_cap(dim) if hist_cap is None else hist_cap
    p = Particles.empty(sum(len(r["pos"]) for r in recs), dim, hist_cap)
    at = 0
    for rec in recs:
        n = len(rec["pos"])
        rows = slice(at, at + n)
        for k in DISC_FIELDS:
            getattr(p, k)[rows] = rec[k]
        hn = p.hist_n[rows]
        if n and (int(hn.max(initial=0)) > hist_cap or int(hn.min(initial=0)) < 0):
            raise StateError(f"contact history counts outside [0, {hist_cap}] (capacity)")
        hn = hn.astype(np.intp)
        total = int(hn.sum())
        dest = csr_slots(np.arange(at, at + n) * hist_cap, hn)  # the slot each entry goes to
        for k in HIST_FIELDS:
            flat = rec[k]
            if len(flat) != total:
                raise StateError(f"{k}: {len(flat)} entries, expected {total} from hist_n")
            a = getattr(p, k)
            a.reshape(a.shape[0] * hist_cap, *a.shape[2:])[dest] = flat
        at += n
    return p


def record_rows(rec: dict[str, np.ndarray], rows) -> dict[str, np.ndarray]:
    """Discs `rows` of a store record (format 2), in that order, as a record."""
    rows = np.asarray(rows, np.intp)
    out = {k: rec[k][rows] for k in DISC_FIELDS}
    hn_all = rec["hist_n"].astype(np.intp)
    entries = csr_slots((np.cumsum(hn_all) - hn_all)[rows], hn_all[rows])
    for k in HIST_FIELDS:
        out[k] = rec[k][entries]
    return out


class V1Epoch:
    """A format-1 epoch read as format 2 (the one place the old format is converted):
    ``read_domain`` stacks x, y -> pos, vx, vy -> vel, w -> spin, hist_ft -> hist_s,
    hist_mr -> hist_m (``state.V1_ARRAYS``), with the same row selection; everything
    else is the wrapped reader's."""

    format_version = 2

    def __init__(self, reader):
        self._reader = reader

    def __getattr__(self, name):
        return getattr(self._reader, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._reader.close()
        return False

    def _names(self, d) -> list[str]:
        raw = list(self._reader.domain_arrays(d))
        comps = {c for cs in V1_ARRAYS.values() for c in cs}
        out = [k for k in raw if k not in comps]
        out += [k for k, cs in V1_ARRAYS.items() if all(c in raw for c in cs)]
        return out

    def domain_arrays(self, d):
        raw = self._reader.domain_arrays(d)
        out = {k: v for k, v in raw.items() if not any(k in cs for cs in V1_ARRAYS.values())}
        for k, cs in V1_ARRAYS.items():
            if all(c in raw for c in cs):
                shape, dt = raw[cs[0]]
                out[k] = (tuple(shape) + (len(cs),), dt)
        return out

    def read_domain(self, d, names=None, rows=None):
        names = self._names(d) if names is None else names
        want = []
        for k in names:
            want += list(V1_ARRAYS.get(k, (k,)))
        raw = self._reader.read_domain(d, want, rows)
        out = {}
        for k in names:
            if k in V1_ARRAYS:
                try:
                    out[k] = stack_v1(k, [raw[c] for c in V1_ARRAYS[k]])
                except ValueError as e:
                    raise StateError(f"epoch {self._reader.step} domain {d}: {e}") from None
            else:
                out[k] = raw[k]
        return out


# an epoch open for reading as open_epoch gives it: a store's EpochReader, or a format-1 one seen
# through V1Epoch (the same methods, not the same type)
OpenEpoch: TypeAlias = Any


def open_epoch(store, step: int | None = None, verify: bool = True) -> OpenEpoch:
    """``store.read_epoch`` seen in the current format (a format-1 epoch through V1Epoch)."""
    reader = store.read_epoch(step, verify=verify)
    v = getattr(reader, "format_version", FORMAT_VERSION)
    if v not in SUPPORTED_VERSIONS:
        reader.close()
        raise StateError(f"epoch {reader.step}: format version {show(v)} is not supported")
    return V1Epoch(reader) if v == 1 else reader


def stored_scenario(meta: dict, where: str):
    """The scenario a run store's meta holds, checked against its hash (StateError)."""
    from .scenario import ScenarioError, scenario_from_toml

    toml = meta.get("scenario_toml")
    if not isinstance(toml, str):
        raise StateError(f"{where}: stored scenario missing (store damaged or edited)")
    try:
        sc = scenario_from_toml(toml)
    except (ScenarioError, ValueError, RecursionError) as e:  # tomllib's errors are ValueErrors
        raise StateError(f"{where}: stored scenario unreadable ({' '.join(str(e).split())})") from None
    if sc.hash() != meta.get("scenario_hash"):
        raise StateError(f"{where}: stored scenario does not match its hash (store damaged or edited)")
    return sc


def stored_layout(meta: dict, where: str, sc=None) -> tuple[int, int, StateBounds | None]:
    """(dim, history capacity, StateBounds) that a run store's epochs are read with, from its
    meta (typed: StateError) and its scenario (`sc`, else the stored one when the meta holds
    one; without a scenario no StateBounds). A run keeps the capacity it was written with
    when that is larger (runs written when 2D's default was 12 may hold discs with more than
    today's 8 contacts), up to the scenario's maximum."""
    from .schema import MAX_HIST_CAP

    if not isinstance(meta, dict):
        raise StateError(f"{where}: store meta is not an object")
    dim = meta.get("dim", 2)  # format 1 was 2D only
    if type(dim) is not int or dim not in (2, 3):
        raise StateError(f"{where}: store meta 'dim' = {show(dim)}: must be the integer 2 or 3")
    cap = meta.get("hist_cap")
    if cap is not None and type(cap) is not int:
        raise StateError(f"{where}: store meta 'hist_cap' = {show(cap)}: must be an integer")
    if cap is not None and not 1 <= cap <= MAX_HIST_CAP:  # no run is written with more
        raise StateError(
            f"{where}: store meta 'hist_cap' = {cap}: not a contact-history capacity (1 to {MAX_HIST_CAP})"
        )
    if sc is None and "scenario_toml" in meta:
        sc = stored_scenario(meta, where)
    if sc is not None and sc.dim != dim:
        raise StateError(
            f"{where}: store holds a {dim}-dimensional run, the stored scenario is "
            f"{sc.dim}-dimensional (store damaged or edited)"
        )
    own = sc.hist_cap if sc is not None else default_hist_cap(dim)
    if cap is not None and own < cap <= MAX_HIST_CAP:
        own = cap
    return dim, own, (state_bounds(sc) if sc is not None else None)


def read_epoch_particles(store, where: str, step: int | None = None):
    """(Particles sorted by id, globals arrays, globals attrs) of a run store's epoch `step`
    (default: the current, or the previous if the current fails verification), validated
    (``validate_epoch``, with the store's ``stored_layout``) before it is read whole."""
    dim, cap, bounds = stored_layout(store.meta or {}, where)
    reader = open_epoch(store, step)
    try:
        validate_epoch(reader, where, dim, cap, bounds)
        arrays, attrs = reader.read_globals()
        return read_all_particles(reader, dim, cap), arrays, attrs
    finally:
        reader.close()


def read_all_particles(reader, dim: int = 2, hist_cap: int | None = None) -> Particles:
    """All discs of an epoch (every domain group), sorted by id."""
    parts = [record_to_particles(reader.read_domain(d), hist_cap) for d in reader.domains()]
    return Particles.concat(parts, dim, hist_cap).sorted_by_id()


def hash_particles(p: Particles, wheel, step: int) -> str:
    """The canonical state hash (``statehash``) of a state in RAM: equal to ``hash_epoch``
    of any store epoch holding the same discs, wheel state and step."""
    return statehash.hash_records([particles_to_record(p)], wheel, step)


def check_bed(p: Particles, where: str, sc) -> None:
    """Refuse a bed (a prepared ``bed.npz``, a cached settled bed) that a store holding it
    would be refused for: the records of ``validate_record`` with the scenario's bounds
    and history capacity, ids unique, and exactly ``soil.n`` discs. In slices of rows,
    so the check holds one slice's record beside the bed."""
    if len(p) != sc.soil.n:
        raise StateError(f"{where}: holds {len(p)} discs, the scenario has soil.n = {sc.soil.n}")
    if p.dim != sc.dim:
        raise StateError(f"{where}: holds {p.dim}D discs, the scenario is {sc.dim}D")
    cap = min(p.hist_cap, sc.hist_cap)
    if len(p) and (int(p.hist_n.min()) < 0 or int(p.hist_n.max()) > cap):
        raise StateError(f"{where}: hist_n outside [0, {cap}] (contact history capacity)")
    bounds = state_bounds(sc)
    for at in range(0, len(p), BED_CHECK_ROWS):
        rec = particles_to_record(p, np.arange(at, min(len(p), at + BED_CHECK_ROWS)))
        validate_record(rec, where, sc.dim, cap, bounds)
    check_unique_sorted(np.sort(p.id), where)


BED_CHECK_ROWS = 1 << 16


def hash_epoch(
    reader, where: str = "", dim: int | None = None, hist_cap: int | None = None, bounds: StateBounds | None = None
) -> str:
    """The canonical state hash of an epoch (``statehash``), streamed group by group and
    validated as it is read (``checked_groups``, the validation of ``validate_epoch``; dim
    None: each record's own): one group's record in RAM at a time, read sequentially, the
    groups' lane sums added."""
    sums, n = statehash.zero(), 0
    for d, rec in checked_groups(reader, where or "store", dim, hist_cap, bounds):
        try:
            sums = statehash.combine(sums, statehash.lane_sums(rec))
        except (KeyError, ValueError) as e:
            raise StateError(f"epoch {reader.step} domain {d}: {e}") from None
        n += len(rec["id"])
    arrays, attrs = reader.read_globals()
    return statehash.finish(sums, n, int(attrs["step"]), arrays.get("wheel_state"))
