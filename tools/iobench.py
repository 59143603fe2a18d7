#!/usr/bin/env python
"""Store I/O benchmark: metadata work per epoch, seconds per sweep, bytes per disc, throughput.

Two measurements, printed as one JSON object:

``sweep``  the out-of-core run of a scenario (default ``quick``, 1500 discs, K = 1: one epoch
           committed per step) per backend: two runs of S1 and S2 steps in this process
           after a warm-up run (JIT), so ``s_per_sweep = (t(S2) - t(S1)) / (S2 - S1)`` holds
           no set-up; file-system objects created and deleted per epoch are counted with
           Python audit hooks (``os.mkdir``, ``open`` for writing, ``os.remove``,
           ``os.rmdir``) over the same difference.
``epoch``  one epoch of N discs (a settled ``bed-N``, its real contact history) written and
           read back through the store API per backend x compression: bytes on disk per disc,
           write and full-read throughput in MB/s of the uncompressed record, and the time of
           a halo-strip read (1 % of the rows of every group).

    python tools/iobench.py                                  # both, defaults
    python tools/iobench.py --only epoch --n 100000 --domains 8
    python tools/iobench.py --only sweep --backends zarr --steps 10,40
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

COUNTED = ("os.mkdir", "os.rmdir", "os.remove", "open")


class _FsCounter:
    """Counts file-system object creations and deletions below `root` (audit hooks)."""

    def __init__(self):
        self.root = None
        self.counts = dict.fromkeys(("mkdir", "create", "unlink", "rmdir"), 0)
        sys.addaudithook(self._hook)

    def _hook(self, event, args):
        if self.root is None or event not in COUNTED:
            return
        if event == "open":
            path, mode, flags = args
            writing = (isinstance(mode, str) and any(c in mode for c in "wxa")) or (
                isinstance(flags, int) and flags & os.O_CREAT
            )
            if not writing:
                return
            key = "create"
        else:
            path = args[0]
            key = {"os.mkdir": "mkdir", "os.rmdir": "rmdir", "os.remove": "unlink"}[event]
        if args[-1] is not None and event != "open" and not os.path.isabs(os.fsdecode(path)):
            self.counts[key] += 1  # rmtree's dir_fd-relative calls: inside the tree it removes
            return
        try:
            p = os.fsdecode(path)
        except TypeError:  # an fd
            return
        if os.path.abspath(p).startswith(self.root):
            self.counts[key] += 1

    def snapshot(self):
        return dict(self.counts)


def _run_sweeps(counter, scenario, backend, steps, compression, tmp):
    import ooc_dem

    out = os.path.join(tmp, f"{backend}-{compression}-{steps}")
    counter.root = os.path.abspath(out)
    before = counter.snapshot()
    kw = {"compression": compression} if compression != "none" else {}
    t = time.perf_counter()
    ooc_dem.run(scenario, out=out, mode="ooc", backend=backend, block=1, steps=steps, **kw)
    el = time.perf_counter() - t
    after = counter.snapshot()
    counter.root = None
    return el, {k: after[k] - before[k] for k in after}


def sweep(args, counter) -> list[dict]:
    s1, s2 = (int(v) for v in args.steps.split(","))
    res = []
    with tempfile.TemporaryDirectory(dir=args.tmp) as tmp:
        _run_sweeps(counter, args.scenario, "hdf5", 2, "none", tmp)  # JIT warm-up
        for backend in args.backends.split(","):
            for comp in args.compressions_for(backend):
                t1, c1 = _run_sweeps(counter, args.scenario, backend, s1, comp, tmp)
                t2, c2 = _run_sweeps(counter, args.scenario, backend, s2, comp, tmp)
                per = {k: round((c2[k] - c1[k]) / (s2 - s1), 1) for k in c1}
                res.append(
                    {
                        "scenario": args.scenario,
                        "backend": backend,
                        "compression": comp,
                        "block": 1,
                        "steps": [s1, s2],
                        "s_per_sweep": round((t2 - t1) / (s2 - s1), 4),
                        "fs_objects_per_epoch": per,
                        "created_per_epoch": per["mkdir"] + per["create"],
                        "deleted_per_epoch": per["unlink"] + per["rmdir"],
                    }
                )
                print(json.dumps(res[-1]), file=sys.stderr)
    return res


def _bed_groups(name, domains):
    import numpy as np
    from ooc_dem.app.bed import settled_bed
    from ooc_dem.model.checkpoint import particles_to_record
    from ooc_dem.physics.layout import AX_X
    from ooc_dem.model.scenario import load_scenario

    bed = settled_bed(load_scenario(name))
    order = np.argsort(bed.pos[:, AX_X], kind="stable")
    parts = np.array_split(order, domains)
    return [particles_to_record(bed.take(rows)) for rows in parts]


def epoch(args) -> list[dict]:
    import numpy as np
    from ooc_dem.storage import create_store

    groups = _bed_groups(args.bed or f"bed-{args.n}", args.domains)
    args.n = sum(len(g["id"]) for g in groups)
    raw = sum(a.nbytes for g in groups for a in g.values())
    res = []
    with tempfile.TemporaryDirectory(dir=args.tmp) as tmp:
        for backend in args.backends.split(","):
            for comp in args.compressions_for(backend):
                path = os.path.join(tmp, f"{backend}-{comp}")
                s = create_store(path, backend, {}, **({} if comp == "none" else {"compression": comp}))
                best_w = best_r = best_h = float("inf")
                for rep in range(args.repeat):
                    t = time.perf_counter()
                    w = s.begin_epoch(10 + rep)
                    for d, g in enumerate(groups):
                        w.write_domain(d, g, {"n": len(g["id"])})
                    w.write_globals({"t": np.zeros(1)})
                    w.commit()
                    best_w = min(best_w, time.perf_counter() - t)
                    r = s.read_epoch()
                    t = time.perf_counter()
                    back = [r.read_domain(d) for d in r.domains()]
                    best_r = min(best_r, time.perf_counter() - t)
                    t = time.perf_counter()
                    for d in r.domains():
                        n = r.domain_len(d)
                        r.read_domain(d, ["pos", "vel", "spin", "r"], slice(0, max(1, n // 100)))
                    best_h = min(best_h, time.perf_counter() - t)
                    r.close()
                    assert all(np.array_equal(back[d][k], groups[d][k]) for d in range(len(groups)) for k in groups[d])
                info = s.list_epochs()[-1]
                s.close()
                res.append(
                    {
                        "backend": backend,
                        "compression": comp,
                        "n_discs": args.n,
                        "domains": args.domains,
                        "record_bytes_per_disc": round(raw / args.n, 1),
                        "disk_bytes_per_disc": round(info.nbytes / args.n, 1),
                        "ratio": round(raw / info.nbytes, 3),
                        "write_MB_s": round(raw / best_w / 1e6, 1),
                        "read_MB_s": round(raw / best_r / 1e6, 1),
                        "strip_read_s": round(best_h, 4),
                    }
                )
                print(json.dumps(res[-1]), file=sys.stderr)
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=["sweep", "epoch"])
    ap.add_argument("--backends", default="hdf5,zarr")
    ap.add_argument(
        "--compressions", default="all", help="comma-separated names, 'none', or 'all' (every one the backend has)"
    )
    ap.add_argument("--scenario", default="quick")
    ap.add_argument("--steps", default="10,40", help="S1,S2 of the sweep measurement")
    ap.add_argument(
        "--sweep-compression",
        action="store_true",
        help="the sweep measurement for every compression too (default: none only)",
    )
    ap.add_argument("--n", type=int, default=100000, help="epoch: the bed-N scenario's N")
    ap.add_argument(
        "--bed",
        help="epoch: a scenario whose settled bed to store instead of bed-N "
        "(bed-N is tiled from copies of one tile, which flatters "
        "compression; e.g. quick or paper2008 are settled whole)",
    )
    ap.add_argument("--domains", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--tmp", default=None, help="directory for the stores (default: the system's)")
    args = ap.parse_args()

    def compressions_for(backend, for_sweep=False):
        from ooc_dem import storage

        have = ["none"] + list(getattr(storage, "COMPRESSIONS", {}).get(backend, ()))
        if args.compressions == "all":
            return have
        return [c for c in args.compressions.split(",") if c in have]

    counter = _FsCounter()
    out = {}
    if args.only in (None, "sweep"):
        args.compressions_for = compressions_for if args.sweep_compression else (lambda b: ["none"])
        out["sweep"] = sweep(args, counter)
    if args.only in (None, "epoch"):
        args.compressions_for = compressions_for
        out["epoch"] = epoch(args)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
