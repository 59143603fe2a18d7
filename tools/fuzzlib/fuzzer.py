"""Running and checking one case: build its world, run the command in the worker (or a fresh
interpreter), check every property; failures classified, a damaged heap found by bisection."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .common import BED_RUN, CASE_TIMEOUT, GiB, MEM_BOUND, READ_ONLY, SAFE_DIRS, SIZE_BOUND, _opt, _sha
from .edits import apply_edit
from .handle import Worker, child_env
from .pools import EXPORT_OUTS_BAD, _without_noop_expectations
from .worker import API_PREFIX
from .world import OTHER_BASE, World, _committed, _diff, make_bases, snapshot


def _command_of(argv) -> tuple[str, str | None]:
    cmd = argv[0] if argv else ""
    sub = argv[1] if cmd == "checkpoint" and len(argv) > 1 else None
    return cmd, sub


def _stderr_lines(text: str) -> list[str]:
    """The non-empty stderr lines but the warnings `check` and `run` print before they start."""
    return [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("ooc-dem: warning: ")]


def failure_class(rec: dict, err: str | None = None) -> str:
    """A short key that groups failures with the same cause."""
    prop = rec["property"]
    cmd = " ".join(x for x in _command_of(rec["argv"]) if x)
    err = (rec.get("stderr") or "") if err is None else err
    where = ""
    if "Traceback" in err:
        frames = re.findall(r'File "([^"]+)", line \d+, in (\S+)', err)
        own = [
            f"{Path(f).parent.name}/{Path(f).name}:{fn}" for f, fn in frames if "ooc_dem" in f and "/fuzzlib/" not in f
        ]
        last = [ln for ln in err.strip().splitlines() if ln and not ln.startswith(" ")][-1:]
        exc = rec.get("exc") or (last[0].split(":")[0] if last else "?")
        where = f"{exc} at {own[-1] if own else (frames[-1][1] if frames else '?')}"
    elif rec.get("exc"):
        where = rec["exc"]
    elif rec.get("error"):
        where = re.sub(r"\d+(\.\d+)?", "N", rec["error"])
    return f"{prop} | {cmd} | {where}".strip(" |")


def fast_tmp() -> str | None:
    """/dev/shm when usable (a case creates and deletes a few hundred files; tmpfs is ~50x faster)."""
    d = "/dev/shm"
    try:
        st = os.statvfs(d)
        if os.access(d, os.W_OK) and st.f_bavail * st.f_frsize > 2 * GiB:
            return d
    except OSError:
        pass
    return None


class Fuzzer:
    """Owns the session directory, the base runs and the worker; runs and checks cases."""

    def __init__(
        self,
        workdir: Path | None = None,
        bases_dir: Path | None = None,
        timeout=CASE_TIMEOUT,
        mem_bound=MEM_BOUND,
        keep_failed: int = 0,
        log=None,
        bisect_budget_s: float = 150.0,
        bases=None,
    ):
        self.bisect_budget_s = bisect_budget_s
        self._tmp = None
        if workdir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="ooc-dem-fuzz-", dir=fast_tmp())
            workdir = Path(self._tmp.name)
        self.work = Path(workdir)
        self.cases_dir = self.work / "cases"
        self.cases_dir.mkdir(parents=True, exist_ok=True)
        self.bases = make_bases(Path(bases_dir) if bases_dir else self.work / "bases", bases)
        self.timeout = timeout
        self.mem_bound = mem_bound
        self.keep_failed = keep_failed
        self.log = log or (lambda msg: None)
        warm = self.work / "warm"
        stores = [b for b in ("h5", "zarr", "h5_3d", "zarr_3d") if b in self.bases]

        def prepare():  # fresh copies before every (re)start of the worker
            shutil.rmtree(warm, ignore_errors=True)
            warm.mkdir()
            for b in stores:
                shutil.copytree(self.bases[b], warm / b)

        tail = ["--no-progress", "--no-figures"]
        self.worker = Worker(
            prepare=prepare,
            errlog=self.work / "worker-stderr.log",
            warmup=[(["resume", b, "--steps", "21", *tail], str(warm)) for b in stores]
            + [(["report", "h5"], str(warm))],
            mem_bound=mem_bound,
        ).start()
        self.commands = set(self.worker.info.get("commands", []))
        # the state hash after `resume --steps 30` of each intact base (made when first needed):
        # a resume that falls back from a damaged current epoch to the previous one must end
        # with these bits
        self.ref_hash = {}
        self.n = 0
        self.slowest: list = []  # (seconds, case) of the slowest cases
        self._current = ""
        self.counts: dict[str, int] = {}
        self.missing: dict[str, int] = {}
        self.inapplicable: dict[str, int] = {}  # cases whose edits the harness could not apply
        self.failures: list[dict] = []
        self.elapsed = 0.0
        self.max_peak = 0
        self.history: list[dict] = []  # the last cases run in the current worker
        self.worker_cases: list[dict] = []  # every case run in the current worker

    def reference(self, base: str, what: str):
        """The state hash (as a one-item list) an intact world ends with: ``resume`` -- the
        base resumed to step 30; ``bed_run`` -- BED_RUN from the intact bed cache."""
        key = (base, what)
        if key not in self.ref_hash:
            ref = self.work / "ref"
            shutil.rmtree(ref, ignore_errors=True)
            ref.mkdir()
            env = None
            if what == "resume":
                shutil.copytree(self.bases[base], ref / "run")
                self.worker.call(["resume", "run", "--steps", "30", "--no-progress", "--no-figures"], ref)
            elif what == "export_previous":
                shutil.copytree(self.bases[base], ref / "run")
                self.worker.call(["checkpoint", "export", "run", "--epoch", "10", "--out", "e.csv"], ref)
                self.ref_hash[key] = _csv_body(ref / "e.csv")
                shutil.rmtree(ref, ignore_errors=True)
                return self.ref_hash[key]
            elif what == "previous":
                shutil.copytree(self.bases[base], ref / "run")
                h = self.worker.call(["checkpoint", "hash", "run", "--epoch", "10"], ref)
                self.ref_hash[key] = (h.get("stdout") or "").strip().splitlines()[-1:] or None
                shutil.rmtree(ref, ignore_errors=True)
                return self.ref_hash[key]
            else:
                shutil.copytree(self.bases["cache"], ref / "cache")
                env = {"OOC_DEM_CACHE": str(ref / "cache")}
                self.worker.call([*BED_RUN, "--out", "run"], ref, timeout=max(self.timeout, 60), env=env)
            h = self.worker.call(["checkpoint", "hash", "run"], ref)
            self.ref_hash[key] = (h.get("stdout") or "").strip().splitlines()[-1:] or None
            shutil.rmtree(ref, ignore_errors=True)
        return self.ref_hash[key]

    def restart_worker(self):
        """A fresh worker (a strategy's cases cannot be hit by an earlier one's heap damage)."""
        self.worker.kill()
        self.worker.kill_cleanup()
        self.worker.restarts += 1
        self.worker.start()
        self.history = []
        self.worker_cases = []

    def end_worker(self, bisect_budget_s: float | None = None) -> None:
        """Stop the worker normally; if it aborts at exit, some case damaged its heap (an
        out-of-bounds write in a kernel): find that case by bisection in fresh workers."""
        cases = self.worker_cases
        self.worker_cases, self.history = [], []
        rc = self.worker.close()
        if rc in (0, None) or not cases:
            return
        why = (
            f"worker exited with {signal.Signals(-rc).name if rc < 0 else rc} at interpreter exit: "
            + " ".join(self.worker.errlog_tail().split())[-300:]
        )
        budget = self.bisect_budget_s if bisect_budget_s is None else bisect_budget_s
        culprit, note = self._bisect(cases, time.monotonic() + budget)
        rec = self._fail(
            culprit or cases[-1],
            "heap_damage",
            why
            + (
                f"; bisected to this case ({note})"
                if culprit
                else f"; not bisected ({note}); {len(cases)} cases ran in that worker"
            ),
            {"rc": rc, "stderr": self.worker.errlog_tail()},
        )
        if not culprit:
            rec["preceded_by"] = [
                {"base": c.get("base"), "argv": short(c["argv"]), "edits": short(c.get("edits", []))}
                for c in cases[-5:]
            ]
        self.failures.append(rec)

    def _aborts(self, cases) -> bool:
        saved = (
            self.n,
            dict(self.counts),
            list(self.failures),
            dict(self.missing),
            dict(self.inapplicable),
            self.elapsed,
            self.max_peak,
        )
        try:
            self.worker.start()
            for c in cases:
                self.run_case(c)
            self.worker_cases = []
            return (
                self.worker.close() not in (0, None)
                or len(self.failures) > len(saved[2])
                and any(f["property"] == "crash_or_timeout" for f in self.failures[len(saved[2]) :])
            )
        finally:
            self.n, self.counts, self.failures, self.missing, self.inapplicable, self.elapsed, self.max_peak = saved
            self.history = []

    def _bisect(self, cases, deadline):
        """The single case that makes a fresh worker abort, or (None, why)."""
        engine = [c for c in cases if _command_of(c["argv"])[0] in ("resume", "run", "sweep", "prepare")]
        if engine and time.monotonic() < deadline and self._aborts(engine):
            cases = engine
        elif time.monotonic() >= deadline or not self._aborts(cases):
            return None, "the abort did not recur"
        while len(cases) > 1:
            if time.monotonic() > deadline:
                return None, f"bisection ran out of time with {len(cases)} candidates"
            half = cases[: len(cases) // 2]
            if self._aborts(half):
                cases = half
            elif self._aborts(cases[len(cases) // 2 :]):
                cases = cases[len(cases) // 2 :]
            else:
                return None, f"needs several of {len(cases)} cases together"
        return cases[0], "it alone makes a fresh worker abort at exit"

    def close(self):
        self.worker.close()
        if self._tmp is not None:
            self._tmp.cleanup()

    # ---- one case
    def run_case(self, case: dict) -> list[dict]:
        t0 = time.monotonic()
        self.n += 1
        self._current = f"{case.get('strategy')} {case.get('base', 'h5')} {' '.join(map(str, case['argv']))[:80]}"
        strategy = case.get("strategy", "?")
        self.counts[strategy] = self.counts.get(strategy, 0) + 1
        root = self.cases_dir / f"c{self.n:06d}"
        shutil.rmtree(root, ignore_errors=True)
        other = OTHER_BASE.get(case.get("base", "h5"), "h5")
        world = World(root, self.bases[case.get("base", "h5")], self.bases[other])
        fails = []
        try:
            if "run2" in json.dumps(case):
                world.add_run2()
            for what in case.get("needs", []):
                world.add_material(what, self.bases)
            for i, ed in enumerate(case.get("edits", [])):
                try:
                    apply_edit(world, ed)
                except (ValueError, UnicodeDecodeError, KeyError, IndexError, TypeError, OSError):
                    if i == 0:
                        raise
                    # an earlier edit damaged what this one edits (e.g. flipped bytes in zarr.json)
        except Exception as e:  # noqa: BLE001 - the harness could not make this case (e.g. h5py
            # refuses a value, or an earlier flip left an HDF5 file h5py cannot edit): nothing of
            # ooc-dem ran, so it is counted as not applicable, never as a pass or a failure
            key = f"{type(e).__name__}: {' '.join(str(e).split())[:80]}"
            self.inapplicable[key] = self.inapplicable.get(key, 0) + 1
            self._finish(root, fails, t0)
            return fails
        if any(ed.get("noop") for ed in case.get("edits", ())):
            case = _without_noop_expectations(case)
        argv = [str(a) for a in case["argv"]]
        cmd, sub = _command_of(argv)
        if cmd == "check" and cmd not in self.commands:
            self.missing[cmd] = self.missing.get(cmd, 0) + 1
            if cmd == "check":
                # `check` not merged yet: `profile SCENARIO --set ... --out victim` validates the
                # scenario and its overrides the same way, then refuses the non-empty --out
                argv = ["profile", argv[1], *_only_sets(argv[2:]), "--modes", "monolithic", "--out", "victim"]
                case = dict(case, argv=argv, via="profile (no `check` command yet)")
                cmd, sub = _command_of(argv)
        skip = [os.path.join("w", d) for d in SAFE_DIRS]
        outside0 = snapshot(root, skip)
        session0 = sorted(os.listdir(self.cases_dir))
        stores0 = {d: snapshot(world.w / d) for d in ("run", "run2")}
        committed0 = _committed(world.run)
        restarts = self.worker.restarts
        env = {"OOC_DEM_CACHE": str(world.w / "cache")} if "cache" in case.get("needs", []) else None
        timeout = max(self.timeout, case.get("timeout", 0))
        if case.get("fresh"):
            res = _fresh_call(argv, world.w, timeout, env, case.get("fsize"))
        else:
            res = self.worker.call(argv, world.w, timeout=timeout, env=env, fsize=case.get("fsize"))
        died = self.worker.proc is None or self.worker.proc.poll() is not None or self.worker.restarts != restarts
        if case.get("fresh"):
            pass  # its own interpreter: nothing to do with the worker's history
        elif res.get("rc") is None and self.history:
            res["preceded_by"] = list(self.history)
        if case.get("fresh"):
            pass
        elif died or res.get("rc") is None:
            self.history, self.worker_cases = [], []
        else:
            self.history = (
                self.history
                + [{"base": case.get("base", "h5"), "edits": short(case.get("edits", [])), "argv": short(argv)}]
            )[-3:]
            self.worker_cases.append(case)
        fails += self.check(case, argv, world, res, outside0, session0, stores0, committed0)
        self._finish(root, fails, t0)
        return fails

    def _finish(self, root, fails, t0):
        dt = time.monotonic() - t0
        self.elapsed += dt
        self.slowest = sorted(self.slowest + [(round(dt, 2), self._current)], key=lambda x: -x[0])[:10]
        self.failures += fails
        if fails and self.keep_failed > 0:
            self.keep_failed -= 1
            for f in fails:
                f["kept_dir"] = str(root)
        else:
            shutil.rmtree(root, ignore_errors=True)

    def _fail(self, case, prop, detail, res) -> dict:
        rec = {
            "strategy": case.get("strategy"),
            "base": case.get("base", "h5"),
            "edits": case.get("edits", []),
            "argv": [str(a) for a in case["argv"]],
            "property": prop,
            "detail": detail,
            "exit_code": res.get("rc"),
            "exc": res.get("exc"),
            "error": res.get("error"),
        }
        if res.get("preceded_by"):
            # a crash may be heap damage done by an earlier case in the same worker
            rec["preceded_by"] = res["preceded_by"]
        err = res.get("stderr") or ""
        rec["stderr"] = err if len(err) <= 3000 else err[:1000] + "\n...\n" + err[-2000:]
        rec["class"] = failure_class(rec, err)
        self.log(f"FAIL [{rec['class']}] {' '.join(rec['argv'])}: {detail}")
        return rec

    def check(self, case, argv, world, res, outside0, session0, stores0, committed0) -> list[dict]:
        fails = []
        cmd, sub = _command_of(argv)
        rc = res.get("rc")
        err = res.get("stderr") or ""
        lines = _stderr_lines(err)
        peak = max(res.get("hwm", 0), res.get("peak_seen", 0))
        self.max_peak = max(self.max_peak, peak)
        if rc is None:
            fails.append(self._fail(case, "crash_or_timeout", res.get("error"), res))
        elif rc not in (0, 2):
            fails.append(
                self._fail(
                    case, "exit_code", f"exit code {rc}" + (f" ({res.get('exc')})" if res.get("exc") else ""), res
                )
            )
        elif rc == 2 and len(lines) != 1:
            fails.append(self._fail(case, "stderr_lines", f"exit 2 with {len(lines)} stderr lines", res))
        elif "Traceback (most recent call last)" in err:
            fails.append(self._fail(case, "traceback", "traceback on stderr", res))
        base_rss = self.worker.info.get("baseline_rss", 0)
        if rc is not None and res.get("hwm_reset") and peak - base_rss > self.mem_bound:
            fails.append(self._fail(case, "memory", f"peak RSS {peak / GiB:.2f} GiB", res))
        elif (
            rc is not None
            and res.get("hwm_reset")
            and case.get("expect", {}).get("size_bound")
            and res.get("hwm", 0) - res.get("rss0", 0) > SIZE_BOUND
        ):
            fails.append(
                self._fail(
                    case,
                    "memory",
                    f"peak RSS {(res['hwm'] - res['rss0']) / 2**20:.0f} MB "
                    f"above the RSS at the call (bound {SIZE_BOUND >> 20} MB) for a hostile "
                    f"declared size",
                    res,
                )
            )
        if (
            rc == 2
            and case.get("expect", {}).get("size_bound")
            and not any(f["property"] == "memory" for f in fails)
            and re.search(r"out of memory|unable to allocate|memoryerror", err, re.I)
        ):
            # refused only because the allocation failed: it was sized by the hostile number
            # (the worker's RLIMIT_AS stops it; a user's machine would swap or be OOM-killed)
            fails.append(
                self._fail(
                    case,
                    "memory",
                    "a hostile declared size was refused only by running out of memory (allocated before any check)",
                    res,
                )
            )
        if rc in (0, 2):
            left = _temporaries(world.w)
            if left:
                fails.append(self._fail(case, "temporary_left", ", ".join(left[:3]), res))
        if rc == 0 and case.get("fsize"):
            cut = _cut_files(world.w, case["fsize"])
            if cut:
                fails.append(
                    self._fail(
                        case,
                        "truncated_output",
                        f"exit 0 under RLIMIT_FSIZE = {case['fsize']} "
                        f"with files of exactly that size (cut at the limit): "
                        f"{', '.join(cut[:3])}",
                        res,
                    )
                )
        # nothing outside the run directories changes
        outside1 = snapshot(world.root, [os.path.join("w", d) for d in SAFE_DIRS])
        if cmd == "animate" and _opt(argv, "--out") is None and rc == 0:
            # `animate RUN` writes RUN.mp4 beside the run directory by design (never inside
            # the store): that one new file is its output, not a stray write
            outside1 = {
                k: v
                for k, v in outside1.items()
                if k in outside0 or not (os.path.dirname(k) == "w" and k.endswith(".mp4"))
            }
        if outside1 != outside0:
            fails.append(self._fail(case, "outside_changed", ", ".join(_diff(outside0, outside1)), res))
        session1 = sorted(os.listdir(self.cases_dir))
        if session1 != session0:
            fails.append(
                self._fail(case, "outside_changed", f"session dir: {sorted(set(session0) ^ set(session1))[:3]}", res)
            )
        # read-only commands leave the stores alone
        out_opt = _opt(argv, "--out") or ""
        read_only = (
            (cmd == "checkpoint" and sub in READ_ONLY and not (sub == "export" and out_opt.startswith("run")))
            or cmd in ("compare", "check", "report", API_PREFIX)
            or (cmd == "profile" and out_opt == "victim")
            or (cmd in ("animate", "export-trajectory") and out_opt.startswith("out/"))
        )
        if read_only and rc is not None:
            for d in ("run", "run2"):
                after = snapshot(world.w / d)
                before = stores0[d]
                if cmd == "report":
                    after = {k: v for k, v in after.items() if not k.startswith("figures")}
                    before = {k: v for k, v in before.items() if not k.startswith("figures")}
                if after != before:
                    fails.append(
                        self._fail(case, "read_only_changed_store", f"{d}: " + ", ".join(_diff(before, after)), res)
                    )
        # exit 2: nothing committed is touched
        if rc == 2:
            committed1 = {k: v for k, v in _committed(world.run).items()}
            lost = [k for k, v in committed0.items() if committed1.get(k) != v and _sha_or_none(world.run / k) != v]
            if lost:
                fails.append(self._fail(case, "committed_changed_on_error", ", ".join(lost[:3]), res))
        # a successful write leaves a verifiable store
        writes = (
            cmd == "resume"
            or (cmd == "checkpoint" and sub == "prune")
            or (cmd == "run" and _opt(argv, "--out") in ("run", "./run"))
        )
        if writes and rc == 0 and _committed(world.run).get("MANIFEST.json") != committed0.get("MANIFEST.json"):
            v = self.worker.call(["checkpoint", "verify", "run"], world.w, timeout=self.timeout)
            if v.get("rc") != 0:
                r2 = dict(res, stderr=(v.get("stderr") or "") + (v.get("stdout") or "")[-500:])
                fails.append(
                    self._fail(
                        case, "store_invalid_after_write", f"`checkpoint verify run` after it: exit {v.get('rc')}", r2
                    )
                )
        # strategy expectations
        exp = dict(case.get("expect", {}))
        if cmd == "checkpoint" and sub == "export" and out_opt in EXPORT_OUTS_BAD:
            exp["refuse"] = f"export --out {out_opt} ({EXPORT_OUTS_BAD[out_opt]}) accepted"
        if exp.get("same_bits_as_intact") and rc == 0:
            h = self.worker.call(["checkpoint", "hash", "run"], world.w, timeout=self.timeout)
            got = (h.get("stdout") or "").strip().splitlines()[-1:]
            want = self.reference(case.get("base", "h5"), "resume")
            if want and got != want:
                fails.append(
                    self._fail(
                        case,
                        "resumed_from_wrong_data",
                        f"resume of a detectably invalid current epoch exited 0 and ended "
                        f"with state hash {got[0][:16] if got else None}... instead of the "
                        f"intact run's {want[0][:16]}... (neither refused nor fell back)",
                        res,
                    )
                )
        if exp.get("hash_fallback") and rc == 0:
            got = (res.get("stdout") or "").strip().splitlines()[-1:]
            want = self.reference(case.get("base", "h5"), "previous")
            if want and got != want:
                fails.append(
                    self._fail(
                        case,
                        "accepted_invalid_epoch",
                        f"`checkpoint hash` of a detectably invalid current epoch printed "
                        f"{got[0][:24] if got else None}... (neither refused nor the previous "
                        f"epoch's {want[0][:24]}...)",
                        res,
                    )
                )
        if exp.get("export_fallback") and rc == 0:
            got = _csv_body(world.w / out_opt)
            want = self.reference(case.get("base", "h5"), "export_previous")
            if got != want:
                fails.append(
                    self._fail(
                        case,
                        "accepted_invalid_epoch",
                        "`checkpoint export` of a detectably invalid current epoch wrote it "
                        "(neither refused nor the previous epoch)",
                        res,
                    )
                )
        made = world.w / (_opt(argv, "--out") or "-")
        # before the resume below, which moves the store on to a later epoch
        if exp.get("same_as_intact_cache") and rc == 0 and (made / "MANIFEST.json").is_file():
            h = self.worker.call(["checkpoint", "hash", str(made.relative_to(world.w))], world.w, timeout=self.timeout)
            got = (h.get("stdout") or "").strip().splitlines()[-1:]
            want = self.reference(case.get("base", "h5"), "bed_run")
            if want and got != want:
                fails.append(
                    self._fail(
                        case,
                        "ran_on_damaged_cache",
                        f"exit 0 with state hash {got[0][:16] if got else None}... instead of "
                        f"{want[0][:16]}... (a damaged bed-cache entry neither rebuilt nor refused)",
                        res,
                    )
                )
        if exp.get("resumable") and rc == 0 and (made / "MANIFEST.json").is_file():
            v = self.worker.call(
                [
                    "resume",
                    str(made.relative_to(world.w)),
                    "--steps",
                    str(exp["resumable"]),
                    "--no-progress",
                    "--no-figures",
                ],
                world.w,
                timeout=max(self.timeout, 30),
            )
            if v.get("rc") != 0:
                r2 = dict(res, stderr=(v.get("stderr") or "") + (v.get("stdout") or "")[-500:])
                fails.append(
                    self._fail(
                        case,
                        "store_refused_by_own_resume",
                        f"exit 0, then `resume` of the store it wrote: exit {v.get('rc')}",
                        r2,
                    )
                )
        if exp.get("refuse") and rc == 0 and (argv[:2] != ["checkpoint", "verify"] or world.epoch_bytes_changed()):
            fails.append(self._fail(case, "accepted_bad_input", exp["refuse"], res))
        return fails

    # ---- summary
    def summary(self) -> dict:
        classes: dict[str, dict] = {}
        for f in self.failures:
            c = classes.setdefault(f["class"], {"count": 0, "example": f})
            c["count"] += 1
        return {
            "cases": self.n,
            "cases_per_strategy": dict(self.counts),
            "elapsed_s": round(self.elapsed, 1),
            "cases_per_s": round(self.n / self.elapsed, 2) if self.elapsed else None,
            "worker_restarts": self.worker.restarts,
            "worker_baseline_rss_mb": round(self.worker.info.get("baseline_rss", 0) / 2**20, 1),
            "max_peak_rss_mb": round(self.max_peak / 2**20, 1),
            "slowest_cases": [f"{t} s {c}" for t, c in self.slowest],
            "commands_missing": dict(self.missing),
            "inapplicable_cases": dict(self.inapplicable),
            "failures": len(self.failures),
            "failure_classes": [
                {
                    "class": k,
                    "count": v["count"],
                    "argv": short(v["example"]["argv"]),
                    "base": v["example"]["base"],
                    "edits": short(v["example"]["edits"]),
                    "exit_code": v["example"]["exit_code"],
                    **({"preceded_by": v["example"]["preceded_by"]} if v["example"].get("preceded_by") else {}),
                    "detail": v["example"]["detail"],
                    "stderr": v["example"]["stderr"][-1500:],
                }
                for k, v in sorted(classes.items())
            ],
        }


def _csv_body(path: Path):
    """An exported CSV without its first line (which names the store), or None."""
    try:
        return path.read_text(errors="replace").split("\n", 1)[1]
    except (OSError, IndexError):
        return None


TEMP_NAME = re.compile(r"\.tmp")


def _temporaries(root: Path) -> list[str]:
    """Names of temporaries (``*.tmp*``) left anywhere below root after a command ended."""
    out = []
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        for n in dirnames + filenames:
            if TEMP_NAME.search(n):
                out.append(os.path.relpath(os.path.join(dirpath, n), root))
    return sorted(out)


def _cut_files(root: Path, limit: int) -> list[str]:
    """Regular files below root of exactly ``limit`` bytes (what a write cut by RLIMIT_FSIZE leaves)."""
    out = []
    for dirpath, _, filenames in os.walk(root, followlinks=False):
        for n in filenames:
            p = os.path.join(dirpath, n)
            try:
                st = os.lstat(p)
            except OSError:
                continue
            if stat.S_ISREG(st.st_mode) and st.st_size == limit:
                out.append(os.path.relpath(p, root))
    return sorted(out)


def _fresh_call(argv, cwd, timeout, env=None, fsize=None) -> dict:
    """The command in a fresh interpreter (`python -m ooc_dem.cli`), as a user runs it: what
    it prints at interpreter exit counts too (pipes: RLIMIT_FSIZE does not cut them)."""
    import resource

    e = child_env()
    e.update(env or {})

    def limits():
        if fsize is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (int(fsize), resource.getrlimit(resource.RLIMIT_FSIZE)[1]))

    t0 = time.monotonic()
    p = subprocess.Popen(
        [sys.executable, "-m", "ooc_dem.cli", *argv],
        cwd=cwd,
        env=e,
        text=True,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
        preexec_fn=limits,
        errors="replace",
    )
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        out, err = p.communicate()
        return {
            "rc": None,
            "error": f"timeout after {timeout:.0f} s",
            "elapsed": timeout,
            "stderr": err[-20000:],
            "stdout": out[-2000:],
        }
    rc = p.returncode
    if rc < 0:
        err += f"\n[killed by signal {signal.Signals(-rc).name}]"
    return {
        "rc": rc,
        "stdout": out[-65536:],
        "stderr": err[-65536:],
        "elapsed": time.monotonic() - t0,
        "exc": None,
        "hwm_reset": False,
    }


def _only_sets(args):
    out = []
    for i, a in enumerate(args):
        if a == "--set" and i + 1 < len(args):
            out += ["--set", args[i + 1]]
    return out


def short(x, n=120):
    """A long argument or value shown as its head and length (reports stay readable)."""
    if isinstance(x, str):
        return x if len(x) <= n else f"{x[:40]}...({len(x)} chars)"
    if isinstance(x, list):
        return [short(v, n) for v in x]
    if isinstance(x, dict):
        return {k: short(v, n) for k, v in x.items()}
    return x


def _sha_or_none(p: Path):
    try:
        return _sha(p) if p.is_file() else None
    except OSError:
        return None
