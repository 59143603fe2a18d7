"""Running a command on MPI ranks: rank 0 runs it (and drives its engine), the others
serve that engine's collective operations until rank 0 says stop."""

from __future__ import annotations

import os
import sys

from .comm import MAKE, STOP, WorkerState, receive_command, run_everywhere, send_command, world
from .ddm import MpiEngine
from .ooc import MpiOocEngine

# the engines rank 0 may have the other ranks make (``comm.announce``), by name
_ENGINES = {cls.name: cls for cls in (MpiEngine, MpiOocEngine)}


def worker_loop(comm) -> None:
    """Ranks other than 0: run rank 0's commands until it says stop."""
    eng = None
    while True:
        name, args = receive_command(comm)
        if name == STOP:
            return
        if name == MAKE:
            kind, made_with = args
            eng = _ENGINES[kind].on_worker(comm, *made_with)
            continue
        assert eng is not None, "rank 0 makes the engine before any of its ops"
        eng.OPS[name](eng, *args)


def run_ranks(command) -> int:
    """A `run` or `resume` under mpiexec with python -m mpi4py semantics: rank 0 runs
    `command()` (the ordinary command, which drives the engine), the others serve it;
    an exception anywhere aborts every rank. A non-zero exit of rank 0 (an error already
    said in one line) stops the waiting ranks and ends the job with that exit code; only
    if they are inside an op (a collective may wait for rank 0) is the job aborted."""
    comm = world()
    if comm.Get_rank() != 0:
        run_everywhere(comm, lambda: worker_loop(comm))
        return 0
    rc = run_everywhere(comm, command)
    if rc and not WorkerState.idle:
        # MPI_Abort ends the job at once, so the launcher may not forward what rank 0 has
        # just written (the one-line error went missing under load): only when it must.
        # The error is said (one line, flushed); MPI's own abort notice would be a second
        sys.stdout.flush()
        sys.stderr.flush()
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 2)
        comm.Abort(int(rc))
    send_command(comm, (STOP, ()))
    return rc
