"""How MPI mode shares the sub-domains out over the ranks: contiguous ranges cut by disc
count, or a scattered share-out when one sub-domain is too large for a cut to balance;
each rank's x intervals and its local decomposition (own sub-domains and ghosts)."""

from __future__ import annotations

import numpy as np


def rank_starts(counts: np.ndarray, ranks: int) -> np.ndarray:
    """starts[r]: the first sub-domain of rank r (contiguous ranges, R + 1 entries),
    cut so that each rank owns about as many discs; every rank gets a sub-domain
    while there are enough of them."""
    D = len(counts)
    before = np.concatenate([[0], np.cumsum(counts)])
    total = before[-1]
    starts = [0]
    for r in range(1, ranks):
        # the boundary nearest the ideal cut (the first one past it could leave almost a
        # whole sub-domain too many on the ranks before: bed-1m, D = 8, R = 2 cut 5 | 3)
        target = r * total / ranks
        s = int(np.searchsorted(before, target, "left"))
        if 0 < s <= D and target - before[s - 1] <= before[s] - target:
            s -= 1
        lo, hi = starts[-1] + 1, D - (ranks - r)
        s = min(lo, D) if hi < lo else min(max(s, lo), hi)
        starts.append(s)
    starts.append(D)
    return np.array(starts, np.int64)


# a scattered share-out is taken only when it lowers the busiest rank's discs by more than
# this fraction of a rank's mean: each sub-domain it separates from its neighbours adds an
# exchange partner, and disc counts are only a proxy for a rank's work
SCATTER_GAIN = 0.05


def rank_domains(counts: np.ndarray, ranks: int) -> np.ndarray:
    """owner[d]: the rank of sub-domain d. Contiguous ranges cut by disc count
    (``rank_starts``), unless giving the largest sub-domains first to the least loaded rank
    balances the ranks clearly better (``SCATTER_GAIN``). That happens when one sub-domain
    holds about 1/R of the discs: the paper's wheel slab is half of paper2008's bin, so
    with the wheel mid-bin two contiguous ranges split 71/29 and {wheel slab}, {left,
    right} 49/51. The ranks compute the same owner from the same (reduced) counts."""
    counts = np.asarray(counts, np.int64)
    D = len(counts)
    contiguous = np.repeat(np.arange(ranks, dtype=np.int64), np.diff(rank_starts(counts, ranks)))
    scattered = np.zeros(D, np.int64)
    load = np.zeros(ranks, np.int64)
    for d in sorted(range(D), key=lambda d: (-counts[d], d)):
        r = int(np.argmin(load))  # the first of the least loaded
        scattered[d] = r
        load[r] += counts[d]
    busiest = lambda own: int(np.bincount(own, weights=counts, minlength=ranks).max())
    if busiest(scattered) < busiest(contiguous) - SCATTER_GAIN * counts.sum() / ranks:
        return scattered
    return contiguous


def rank_intervals(owner: np.ndarray, bounds: np.ndarray, r: int) -> np.ndarray:
    """The x intervals [lo, hi) rank r owns (its runs of neighbouring sub-domains, merged),
    shape (k, 2); empty for a rank without sub-domains."""
    out: list[list[np.intp]] = []
    for d in np.flatnonzero(owner == r):
        if out and out[-1][1] == d:
            out[-1][1] = d + 1
        else:
            out.append([d, d + 1])
    return np.array([[bounds[a], bounds[b]] for a, b in out], np.float64).reshape(-1, 2)


def rank_segments(owner: np.ndarray, bounds: np.ndarray, r: int) -> tuple[np.ndarray, np.ndarray]:
    """Rank r's local decomposition: (segment bounds, the global sub-domain of each segment
    or -1). Its own sub-domains are segments as they are; each run of other ranks'
    sub-domains between them (and beyond them) is one *ghost* segment."""
    lb: list[float] = [-np.inf]
    glob: list[int] = []
    for d in range(len(owner)):
        if owner[d] != r and glob and glob[-1] < 0:
            lb[-1] = bounds[d + 1]  # the ghost before grows
        else:
            glob.append(int(d) if owner[d] == r else -1)
            lb.append(bounds[d + 1])
    return np.array(lb, np.float64), np.array(glob, np.int64)
