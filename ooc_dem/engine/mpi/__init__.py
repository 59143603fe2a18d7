"""MPI mode: ranks own serial DDM's sub-domains (slabs along x); ``MpiOocEngine`` is
out-of-core on ranks (``ooc.py``).

The package: ``comm`` (the launcher, rank 0's commands, the collective operations, the
abort), ``rows`` (the exchange rows and their kernels), ``shares`` (the sub-domains'
share-out over the ranks), ``ddm`` (``MpiEngine``), ``ooc`` (``MpiOocEngine``) and
``ranks`` (rank 0 runs the command, the others serve it).

Serial DDM (live.py) keeps every sub-domain with its halo in RAM; a sweep is (1) every
halo copy refreshed from its owner's time-n copy, (2) ownership from x, (3) every
sub-domain K steps with THE per-domain step. Here rank r holds the ``LiveDomains`` of
its own sub-domains only (``rank_domains``: contiguous ranges cut by disc count, or a
scattered share-out when one sub-domain is too large for the cut to balance), plus
*ghost* sub-domains: each run of x between and beyond them that other ranks own. A
ghost is never advanced; its rows are the copies of the discs the other ranks own
within a strip (halo + membership skin) of this rank's intervals, and they are what
halo rows of the rank's own sub-domains are refreshed from. So the refresh of copies
whose owner is on another rank becomes, once per block, an exchange with the ranks
within that strip (the neighbours): one round in which every rank posts its sends of
one float64 buffer of disc rows (``row_words``: the id and the moving fields) and
receives each partner's at its probed size, written into the ghost rows by compiled
kernels. A disc that crosses into another rank's sub-domain is in that rank's ghost
already (it was within the strip), so migration needs nothing more: after the refresh
the new owner has its time-n state and ownership from x hands it over, contact
history included.

Why the bits equal serial DDM's (and so the monolithic run's): each sub-domain's local
set is exactly the one serial DDM builds (every disc within halo + membership skin of
its slab), every halo row holds its owner's time-n state before the step, and the step
is the same; memory order and extra discs never change a result (docs/design.md §3).
Everything that decides the schedule - re-decompositions (the wheel leaving its slab),
the wheel's slab, rebuilds of the local sets (a disc moved beyond the membership skin
anywhere) - is computed identically on every rank from data every rank has (the
bounds, the wheel state and the largest move, both from the block's ``Allreduce``), so
the ranks never disagree about what comes next.

The wheel lives on the rank that owns its slab. One ``Allreduce`` (MAX) ends each
block: every rank's largest disc move since the local sets were built, and the wheel's
state and the block's wheel records from the wheel's rank (-inf from the others). The
halo refresh from the owners' rows and the ownership update run inside the compiled
sweep. Re-decompositions use the serial rule on
the x histogram of every disc (``decomposition.XHistogram``, an ``Allreduce`` of its
integer counts) and share the sub-domains out again by disc count. A rebuild sends every
rank the discs within its strip (``alltoall`` of pickled parts: first cut, only
neighbours get non-empty ones).

Driving: rank 0 runs the ordinary ``Simulation`` (store, metrics, trajectory, outputs)
with an ``MpiEngine``; every engine call broadcasts a command - the name of one of the
engine's collective operations (its ``OPS`` table) and its arguments - that the other
ranks' ``worker_loop`` runs on their own engine, made when rank 0 announced it
(``comm.announce``, the engine's ``on_worker``). Checkpoints: rank 0 gathers the owned discs of each
sub-domain (one epoch in rank 0's RAM: first cut) and commits the epoch through the
store exactly as serial DDM does, so any epoch resumes with any number of ranks, or
serially. A failure on any rank aborts the whole job (``MPI_Abort``), never a hang.
"""

from __future__ import annotations

from .comm import launched, run_everywhere, world
from .ddm import MpiEngine
from .ooc import MpiOocEngine
from .ranks import run_ranks
from .rows import row_words
from .shares import rank_domains, rank_intervals, rank_segments, rank_starts

__all__ = [
    "MpiEngine",
    "MpiOocEngine",
    "launched",
    "rank_domains",
    "rank_intervals",
    "rank_segments",
    "rank_starts",
    "row_words",
    "run_everywhere",
    "run_ranks",
    "world",
]
