"""MPI mode's communication outside the block step: the launcher's environment, the world,
rank 0's commands to the other ranks (``send_command``, ``receive_command``), the
collective operations they run (``collective``: each engine's ``OPS`` table), the wheel's
broadcast, and the abort on any rank's failure (``run_everywhere``)."""

from __future__ import annotations

import os
import pickle
import sys
import time

import numpy as np

from ...physics.layout import WS_SIZE
from ..stepper import N_REC, EngineError

# the environment a launcher gives each process: (world size, rank) variable names
_LAUNCHER_ENV = (
    ("PMI_SIZE", "PMI_RANK"),  # MPICH hydra, Intel MPI
    ("OMPI_COMM_WORLD_SIZE", "OMPI_COMM_WORLD_RANK"),  # Open MPI
    ("MV2_COMM_WORLD_SIZE", "MV2_COMM_WORLD_RANK"),
)  # MVAPICH


def launched() -> tuple[int, int]:
    """(world size, rank) as the MPI launcher set them, without initialising MPI;
    (1, 0) for a process not started by mpiexec."""
    for size, rank in _LAUNCHER_ENV:
        if size in os.environ:
            try:
                return int(os.environ[size]), int(os.environ.get(rank, "0"))
            except ValueError:
                break
    return 1, 0


def world():
    """MPI.COMM_WORLD (mpi4py initialises MPI on first import; a lone process is a
    one-rank world)."""
    try:
        from mpi4py import MPI
    except ImportError:
        raise EngineError("--mode mpi needs mpi4py and an MPI: pip install 'ooc-dem[mpi]'") from None
    return MPI.COMM_WORLD


def broadcast_wheel(comm, root: int, ws: np.ndarray, rec: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Rank `root`'s wheel state and its (at most k) wheel records, on every rank: one
    ``Bcast`` of one buffer."""
    buf = np.zeros(WS_SIZE + 1 + k * N_REC)
    if comm.Get_rank() == root:
        buf[:WS_SIZE] = ws
        buf[WS_SIZE] = len(rec)
        buf[WS_SIZE + 1 : WS_SIZE + 1 + rec.size] = rec.ravel()
    if comm.Get_size() > 1:
        comm.Bcast(buf, root=root)
    rows = int(buf[WS_SIZE])
    return buf[:WS_SIZE].copy(), buf[WS_SIZE + 1 : WS_SIZE + 1 + rows * N_REC].reshape(rows, N_REC).copy()


class WorkerState:
    """Rank 0's knowledge of where the other ranks are: waiting for a command (none sent
    yet, or the last op returned on rank 0, so theirs did too), or inside one, where a
    collective may wait for rank 0."""

    idle = True


# the commands that are no collective operation: after them the other ranks wait for the next
STOP = "stop"  # the job is over
MAKE = "make"  # (engine name, its arguments): make the engine whose operations follow


def send_command(comm, command) -> None:
    """Rank 0 -> every rank: its length (a non-blocking broadcast, which the others poll
    with sleeps), then the pickled command (name, args)."""
    from mpi4py import MPI

    WorkerState.idle = command[0] in (STOP, MAKE)
    data = bytearray(pickle.dumps(command))
    comm.Ibcast(np.array([len(data)], np.int64), root=0).Wait()
    comm.Bcast([data, MPI.BYTE], root=0)


def receive_command(comm):
    """The other ranks: wait for rank 0's next command without spinning. Between
    commands rank 0 alone works (commits, outputs); a busy-waiting MPI would take the
    cores from it when ranks share them."""
    from mpi4py import MPI

    n = np.zeros(1, np.int64)
    req = comm.Ibcast(n, root=0)
    while not req.Test():
        time.sleep(0.002)
    data = bytearray(int(n[0]))
    comm.Bcast([data, MPI.BYTE], root=0)
    return pickle.loads(data)


def collective(engine, name: str, args: tuple, **local):
    """Rank 0: every rank runs the operation ``engine.OPS[name]`` with ``args`` (broadcast:
    the other ranks' ``worker_loop`` runs it on their engine); ``local`` stays here."""
    op = engine.OPS[name]
    if engine.R > 1:
        send_command(engine.comm, (name, args))
    out = op(engine, *args, **local)
    WorkerState.idle = True
    return out


def announce(engine, args: tuple) -> None:
    """Rank 0: the other ranks make their engine of ``engine``'s kind from ``args``
    (its ``on_worker``)."""
    if engine.R > 1:
        send_command(engine.comm, (MAKE, (engine.name, args)))


def run_everywhere(comm, command) -> int:
    """Every rank runs ``command()`` (its share of a job such as the sweep's runs); an
    uncaught exception anywhere aborts every rank instead of leaving the others waiting."""
    try:
        rc = command()
    except BaseException:
        import traceback

        traceback.print_exc()
        sys.stderr.flush()
        comm.Abort(1)
        raise
    sys.stdout.flush()
    sys.stderr.flush()
    return rc
