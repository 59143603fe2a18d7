"""`ooc-dem checkpoint`: list, verify, inspect, hash, prune and export the epochs of a store."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .cli_parser import CliError, one_line as _one_line

if TYPE_CHECKING:
    from ooc_dem.storage import Leftover, Store


def _store_leftovers(store: Store, manifest: dict[str, Any] | None = None) -> list[Leftover]:
    """Temporaries and unnamed epoch files of a store (what `resume` would delete)."""
    return store.leftovers(manifest)


def _live_writers(store: Store) -> list[int]:
    """Pids of running processes writing the store (its lock holder, temporaries' writers)."""
    return store.live_writers()


def _read_manifest(store: Store) -> dict[str, Any]:
    """The store's validated manifest as it is now (a run may have committed since opening)."""
    return store.manifest(fresh=True)


def _checkpoint_list(store: Store, path: str) -> None:
    infos = store.list_epochs()
    if not infos:
        print(f"{path}: no committed epoch")
        return
    for info in infos:
        line = f"epoch {info.step:>10d}  {info.path}  {info.nbytes / 1e6:8.3f} MB  domains {info.n_domains}"
        bad = info.problems
        if bad:
            print(f"{line}  DAMAGED ({bad[0]}{f' and {len(bad) - 1} more' if len(bad) > 1 else ''}) ({info.role})")
            continue
        try:
            r = store.read_epoch(info.step, verify=False)  # sizes match; `verify` checks the bytes
            try:
                _, attrs = r.read_globals()
                n = sum(r.domain_len(d) for d in r.domains())
            finally:
                r.close()
            t = attrs.get("time", 0)
            t = f"{t:.6f}" if isinstance(t, (int, float)) else "?"
            print(f"{line}  t = {t} s  discs {n}  ({info.role})")
        except Exception as ex:  # noqa: BLE001 - listing goes on; `verify` names the problem
            print(f"{line}  UNREADABLE ({_one_line(ex)}) ({info.role})")


def _checkpoint_verify(store: Store, args: argparse.Namespace) -> int:
    problems = store.verify(args.epoch)
    if args.epoch is None and store.current() is None:
        print(f"{args.store}: no committed epoch (nothing to verify)")
    m = _read_manifest(store)
    if problems:
        # a run writing the store may have replaced an epoch while it was being checked
        named = {e["step"] for e in (m["current"], m["previous"]) if e}
        gone = {p.step for p in problems if p.step is not None and p.step not in named}
        for s in sorted(gone):
            print(
                f"note: epoch {s} was superseded by a newer commit while being verified (a run is writing this store)"
            )
        problems = [p for p in problems if p.step not in gone]
    for x in _store_leftovers(store, m):
        if x.running:
            print(f"note: {x.path}: epoch being written by running process {x.pid}")
        else:
            print(
                f"warning: {x.path}: leftover of an interrupted write, not part of any committed "
                f"epoch (`ooc-dem resume` deletes it)"
            )
    if problems:
        for pr in problems:
            print(f"FAIL {_one_line(pr)}")
        bad = {p.step for p in problems}
        cur, prev = m["current"], m["previous"]
        hint = ""
        if args.epoch is None and cur and cur["step"] in bad:
            hint = (
                f"; `ooc-dem resume` falls back to epoch {prev['step']}"
                if prev and prev["step"] not in bad
                else "; no intact epoch to resume from"
            )
        raise CliError(f"{args.store}: {len(problems)} problem(s) found{hint}")
    which = store.epochs() if args.epoch is None else [args.epoch]
    print(f"OK: {args.store} epochs {which} verified")
    return 0


def _checkpoint_prune(args: argparse.Namespace) -> int:
    from ooc_dem.storage import open_store

    with open_store(args.store, repair=False) as looking:
        live = _live_writers(looking)
    if live:
        raise CliError(
            f"{args.store}: a run is writing this store (pid {', '.join(map(str, live))}); "
            f"prune it when the run has stopped"
        )
    store = open_store(args.store, repair=True)  # the write lock: no run can start meanwhile
    try:
        for p in store.repaired:
            print(f"removed leftover {p}")
        cur = store.current()
        if cur is None:
            print(f"{args.store}: no committed epoch (nothing to prune)")
            return 0
        # never leave only a damaged epoch: the one kept must verify first
        bad = store.verify(cur)
        if bad:
            raise CliError(
                f"{args.store}: refusing to prune: current epoch {cur} fails verification "
                f"({_one_line(bad[0])}); the previous epoch is its fallback"
            )
        before = {info.step: info.path for info in store.list_epochs()}
        removed = store.prune(args.keep)
        for s in removed:
            print(f"removed epoch {s} ({before.get(s, '?')})")
        if not removed:
            print(f"nothing to remove: {len(before)} committed epoch(s), keeping up to {args.keep}")
        print(f"kept epochs {store.epochs()} (current {cur})")
        for w in store.warnings:
            print(f"warning: {_one_line(w)}")
        return 0
    finally:
        store.close()


def _checkpoint_export(store: Store, args: argparse.Namespace) -> int:
    from ..model.state_check import StateError
    from .export import export_snapshot, infer_format, read_snapshot
    from .export_formats import output_files
    from .outfile import ExportError, check_targets

    fmt = args.format or infer_format(args.out)
    if fmt is None:
        raise CliError(f"--out {args.out}: cannot tell the format from the suffix; give --format xdmf|vtk|csv")
    out = Path(args.out)
    try:
        check_targets(output_files(fmt, out), out)  # before reading anything
        from ..model.checkpoint import open_epoch, stored_layout
        from ..model.state_check import validate_epoch

        dim, cap, bounds = stored_layout(store.meta or {}, args.store)
        reader = open_epoch(store, args.epoch)
        try:
            validate_epoch(reader, args.store, dim, cap, bounds)
            # sorted on disk beside the output (never inside the store): bounded memory
            snap = read_snapshot(reader, args.store, workdir=out.resolve().parent)
        finally:
            reader.close()
        with snap:
            files = export_snapshot(snap, fmt, out)
    except (ExportError, StateError) as e:
        raise CliError(str(e)) from None
    _warn_fallback(store)  # after the work: a refusal stays one line
    print(
        f"exported epoch {snap.step} ({len(snap)} {'spheres' if dim == 3 else 'discs'}, t = {snap.time:.6f} s) "
        f"as {fmt}: " + ", ".join(map(str, files))
    )
    return 0


def _warn_fallback(store: Store) -> None:
    for w in store.warnings:
        print(f"ooc-dem: warning: {_one_line(w)}", file=sys.stderr)


def cmd_checkpoint(args: argparse.Namespace) -> int:
    from ..model.checkpoint import hash_epoch, open_epoch, stored_layout
    from ..model.state_check import validate_globals
    from ooc_dem.storage import open_store

    if args.ckpt_command == "prune":
        return _checkpoint_prune(args)
    # read-only: no repair (a running writer's temporary epoch must not be deleted under it)
    store = open_store(args.store, repair=False)
    try:
        if args.ckpt_command == "list":
            _checkpoint_list(store, args.store)
            return 0
        if args.ckpt_command == "verify":
            return _checkpoint_verify(store, args)
        if args.ckpt_command == "export":
            return _checkpoint_export(store, args)
        layout = stored_layout(store.meta or {}, args.store) if args.ckpt_command == "hash" else None
        reader = open_epoch(store, args.epoch)
        try:
            if layout is not None:  # hash (its layout read above)
                # streamed and validated as read: a store larger than RAM hashes too
                out = hash_epoch(reader, args.store, *layout)
            else:  # inspect
                arrays, attrs = reader.read_globals()
                validate_globals(arrays, attrs, f"{args.store}: epoch {reader.step}", reader.step)
                info = {
                    "step": attrs["step"],
                    "time": attrs.get("time"),
                    "discs": sum(reader.domain_len(d) for d in reader.domains()),
                    "domains": {str(d): reader.domain_len(d) for d in reader.domains()},
                    "wheel_state": [float(v) for v in arrays["wheel_state"]],
                    "mode": attrs.get("mode"),
                }
                out = json.dumps(info, indent=2)
        finally:
            reader.close()
        _warn_fallback(store)  # after the work: a refusal stays one line
        print(out)
        return 0
    finally:
        store.close()
