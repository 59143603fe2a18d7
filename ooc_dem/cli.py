"""`ooc-dem` command line. Every user error is one line on stderr and exit code 2.

The parser is ``app/cli_parser.py``, the commands ``app/cli_commands.py`` and
``app/cli_checkpoint.py``; here the dispatch: under mpiexec, rank 0 runs the command and
the other ranks serve its engine (``engine.mpi``).
"""

from __future__ import annotations

import sys

from .app.cli_checkpoint import cmd_checkpoint
from .errors import OocDemError
from .app.cli_commands import (
    cmd_animate,
    cmd_check,
    cmd_compare,
    cmd_experiment,
    cmd_export_trajectory,
    cmd_prepare,
    cmd_profile,
    cmd_report,
    cmd_resume,
    cmd_run,
    cmd_scenarios,
    cmd_calibrate,
    cmd_shear,
    cmd_sinkage,
    cmd_sweep,
)
from .app.cli_parser import EXIT_USAGE, CliError, build_parser, one_line as _one_line

__all__ = ["CliError", "build_parser", "main"]


COMMANDS = {
    "run": cmd_run,
    "check": cmd_check,
    "prepare": cmd_prepare,
    "resume": cmd_resume,
    "checkpoint": cmd_checkpoint,
    "scenarios": cmd_scenarios,
    "export-trajectory": cmd_export_trajectory,
    "animate": cmd_animate,
    "report": cmd_report,
    "compare": cmd_compare,
    "sweep": cmd_sweep,
    "calibrate": cmd_calibrate,
    "experiment": cmd_experiment,
    "shear": cmd_shear,
    "sinkage": cmd_sinkage,
    "profile": cmd_profile,
}


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    known = OocDemError  # every error for the user: its one-line message, exit 2
    if args.command in ("run", "resume"):
        from .engine.mpi import launched, run_ranks

        if launched()[0] > 1:  # under mpiexec: rank 0 runs the command, the others serve it
            return run_ranks(lambda: _dispatch(args, known))
    if args.command in ("sweep", "experiment"):
        from .engine.mpi import launched, run_everywhere, world

        if launched()[0] > 1:  # under mpiexec: the slips' runs fan out over the ranks
            args.comm = world()
            # the same plan on every rank fails alike: rank 0 alone says so
            return run_everywhere(args.comm, lambda: _dispatch(args, known, quiet=args.comm.Get_rank() != 0))
    return _dispatch(args, known)


def _dispatch(args, known, quiet: bool = False) -> int:
    try:
        return COMMANDS[args.command](args)
    except known as e:
        msg = _one_line(e) or type(e).__name__
        if not quiet:
            print(f"ooc-dem: error: {msg}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt as e:
        # a run says where it stopped and from which step `resume` continues
        said = str(e) if e.args else "interrupted (the last committed epoch is kept; `ooc-dem resume` continues)"
        print(f"ooc-dem: {said}", file=sys.stderr)
        return 130
    except OSError as e:
        where = f"{e.filename}: " if e.filename else ""
        print(f"ooc-dem: error: {where}{_one_line(e.strerror or e)}", file=sys.stderr)
        return EXIT_USAGE
    except MemoryError as e:
        # the plan refuses runs that cannot fit (estimated); this is the machine disagreeing
        detail = _one_line(e) or "an allocation failed"
        print(f"ooc-dem: error: out of memory ({detail}); the last committed epoch is kept", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
