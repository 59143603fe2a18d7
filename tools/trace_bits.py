"""The bits of the pinned 3D Hertz case, stage by stage: where two machines first part.

The pinned 3D Hertz hashes (tests/test_kernel_bits.py) say only THAT the final state
differs. This trace of the pinned quick-3d case (Hertz soil-soil with rolling resistance,
Hertz soil-wheel, linear walls; 2900 spheres) says where: a digest (XXH3-128 of the dtype,
shape and raw bytes) of each array or, for a scalar, its exact value (float.hex), at each
stage:

- ``constants quick-3d`` (and ``... settling``, the model the bed settles with):
  every set-up constant the kernels receive, one entry a field: the contact table's
  records (``cp[soil,wheel].beta``), the walls, the wheel's geometry and controls, gravity,
  dt, skin; ``constants bed3d-20000-hertz``: those of the other pinned Hertz case;
- ``fill quick-3d``: every state array of the bed generated before settling (and
  ``fill bed3d-20000-hertz``: the other case's tile, not stepped here);
- ``settle step k``: every state array after step k of settling, stepped and checked as
  ``app.bed.settle`` does (steps 1 to 20, then checkpoints), then ``bed (settled in N
  steps)``: the settled bed as a run starts from it (at rest, by id);
- ``wheel start``, ``run step k``: the wheel placed on that bed (``place_wheel``), then
  after step k of ``ooc-dem run quick-3d`` every state array, every field of the wheel's
  state and of its step record (forces, torque, contacts) and the lugs' directions
  (``wheel.lug_directions``: the step's cos and sin);
- ``state_hash``: the final state's hash, the pinned run's (test_kernel_bits.QUICK3D_3000).

State arrays are taken in id order with unused history slots zeroed (as the state hash
takes them), vectors one component at a time (``pos[y]``, ``hist_s[z]``); ``order`` is the
ids in the stepper's memory order. A trace also holds, as information never compared: the
machine's facts (CPU, glibc, numpy and its SIMD targets, numba and its target CPU),
``cached_bed`` (whether this machine's bed cache holds the bed just settled: the pinned
runs read the cache), and ``correctly_rounded``: the set-up values against their correctly
rounded values (decimal and fractions arithmetic, no libm): ``ln`` of the restitution
(exactmath), the masses and inertias (exact operations in the model's order), and, counted
only, the lugs' ``cos`` and ``sin`` (detmath: within an ulp, not always correctly rounded).

Usage:
    python tools/trace_bits.py                 # this machine's trace, JSON on stdout
    python tools/trace_bits.py --write FILE    # ... written to FILE
    python tools/trace_bits.py --compare FILE  # the first stage that differs from FILE's
                                               # trace, one message; exit 1 if one does

The fixture tests/data/trace_hertz_quick3d.json is this tool's trace;
tests/test_trace_bits.py recomputes it and names the first stage that differs
(docs/reference/bits.md). Regenerate it (``python tools/trace_bits.py --write
tests/data/trace_hertz_quick3d.json``) only when the bits are meant to move: when the pinned
quick-3d hash of test_kernel_bits.py is re-recorded with a reason, or when the trace itself
changes (its case, checkpoints or entries). A mismatch on another machine is a finding to
send (the test prints the path of that machine's trace), not a reason to regenerate.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
from decimal import Decimal, localcontext
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import xxhash

FORMAT = 1
# the pinned quick-3d case of tests/test_kernel_bits.py: its bed settled as `app.bed.settle`
# settles it, then RUN_STEPS of `ooc-dem run quick-3d --steps 3000` (monolithic)
CASE = "quick-3d"
RUN_STEPS = 3000
FIRST_STEPS = 20  # every step up to here, then the checkpoints
SETTLE_CHECKPOINTS = (100, 500, 1000, 2000, 5000, 10000)
RUN_CHECKPOINTS = (100, 500, 1000, 2000, RUN_STEPS)
# the other pinned Hertz case: its constants and its tile's fill (not stepped here)
OTHER = {"bed3d-20000-hertz": ("bed3d-20000", ["contact.soil_soil.law=hertz", "contact.soil_wall.law=hertz"])}
# wheel angles whose lug cos and sin are checked (quick-3d's wheel turns only after 5000 steps)
LUG_THETAS = (0.0, -0.3, -1.7, -4.9)
AXES = "xyz"
TYPE_NAMES = ("soil", "wall", "wheel")  # physics.layout T_SOIL, T_WALL, T_WHEEL


def digest(a: Any) -> str:
    """XXH3-128 of an array's dtype, shape and raw bytes."""
    a = np.ascontiguousarray(a)
    h = xxhash.xxh3_128()
    h.update(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())
    return h.hexdigest()


def exact(x: float) -> str:
    return float(x).hex()


def record_entries(prefix: str, rec: np.ndarray) -> dict[str, str]:
    """One entry a field of a one-row record (its exact value)."""
    return {f"{prefix}.{name}": exact(rec[name][0]) for name in rec.dtype.names}


def model_entries(model) -> dict[str, str]:
    """Every constant the kernels receive of a model, one entry a field."""
    cp, walls, wg, wc = model.records()
    out: dict[str, str] = {"dt": exact(model.dt), "skin": exact(model.skin)}
    out.update({f"gravity[{AXES[k]}]": exact(g) for k, g in enumerate(model.gravity)})
    for a in range(cp.shape[0]):
        for b in range(a, cp.shape[1]):
            for name in cp.dtype.names:
                out[f"cp[{TYPE_NAMES[a]},{TYPE_NAMES[b]}].{name}"] = exact(cp[a, b][name])
            # the table is symmetric: the kernels read either record
            if cp[a, b].tobytes() != cp[b, a].tobytes():
                out[f"cp[{TYPE_NAMES[b]},{TYPE_NAMES[a]}]"] = digest(cp[b, a])
    out.update(record_entries("walls", walls))
    out.update(record_entries("wheel_geometry", wg))
    out.update(record_entries("wheel_controls", wc))
    return out


def state_entries(p) -> dict[str, str]:
    """Every state array of particles p in id order (unused history slots zeroed), vectors
    one component at a time; ``order``: the ids in memory order."""
    from ooc_dem.model.state import ALL_FIELDS, HIST_FIELDS

    out = {"order": digest(p.id)}
    q = p.sorted_by_id()
    used = np.arange(q.hist_cap)[None, :] < q.hist_n[:, None]
    for name in ALL_FIELDS:
        a = getattr(q, name)
        if name in HIST_FIELDS:
            a = np.where(used.reshape(used.shape + (1,) * (a.ndim - 2)), a, np.zeros((), a.dtype))
        if a.ndim >= 2 and name != "hist_id":
            for k in range(a.shape[-1]):
                out[f"{name}[{AXES[k]}]"] = digest(a[..., k])
        else:
            out[name] = digest(a)
    return out


def lug_entries(ws: np.ndarray, model) -> dict[str, str]:
    """The lugs' directions the step computes at the wheel's angle (its cos and sin)."""
    from ooc_dem.physics.layout import LUG_DIRECTION, WHEEL_GEOMETRY, WS_THETA, record
    from ooc_dem.physics.wheel import lug_directions

    nlugs = int(record(model.wg, WHEEL_GEOMETRY)["nlugs"][0])
    lugdir = np.zeros(nlugs, LUG_DIRECTION)
    lug_directions(float(ws[WS_THETA]), nlugs, lugdir)
    return {"lugs.ux": digest(lugdir["ux"]), "lugs.uy": digest(lugdir["uy"])}


def wheel_entries(ws: np.ndarray, rec: np.ndarray | None = None) -> dict[str, str]:
    from ooc_dem.physics.layout import WHEEL_RECORD, WS_NAMES

    out = {f"wheel.{name}": exact(ws[k]) for k, name in enumerate(WS_NAMES)}
    if rec is not None:
        out.update({f"record.{name}": exact(rec[k]) for k, name in enumerate(WHEEL_RECORD.names)})
    return out


def scenario(name: str, sets: list[str]):
    from ooc_dem.model.scenario import load_scenario

    return load_scenario(name, sets)


def pinned_fill(sc):
    """The bed a pinned case settles: its own fill, or its tile's (a tiled bed)."""
    from ooc_dem.app.bed import initial_fill
    from ooc_dem.model.scenario_check import tile_scenario

    return initial_fill(tile_scenario(sc) if sc.bed.tile > 0 and sc.soil.n > sc.bed.tile else sc)


def marks(checkpoints: tuple[int, ...]) -> set[int]:
    return set(range(1, FIRST_STEPS + 1)) | set(checkpoints)


def step_stage(label: str, stepper, model=None, rec=None) -> dict[str, Any]:
    """Every state array after a step (and the wheel's, with a model)."""
    entries = state_entries(stepper.p)
    if model is not None:
        entries.update(wheel_entries(stepper.ws, rec))
        entries.update(lug_entries(stepper.ws, model))
    return {"stage": label, "entries": entries}


def settle_traced(sc, p, stages: list) -> tuple[Any, int]:
    """``app.bed.settle`` with a stage at each of its first steps and checkpoints: the same
    model, the same steps, the same checks of the speed (the bits do not depend on where
    the steps are cut: design.md section 3)."""
    from ooc_dem.app.bed import BedError, mean_speed, pour_scenario, settle_schedule
    from ooc_dem.engine.stepper import DomainStepper, Model

    model = Model.from_scenario(pour_scenario(sc)).without_wheel()
    stepper = DomainStepper(p, model)
    chunk, min_steps, max_steps = settle_schedule(sc)
    at = marks(SETTLE_CHECKPOINTS)
    step = 0
    while True:
        to = min([k for k in at if k > step] + [(step // chunk + 1) * chunk])
        stepper.advance(step, to - step)
        step = to
        if step in at:
            stages.append(step_stage(f"settle step {step}", stepper))
        if step % chunk == 0:
            if step >= min_steps and mean_speed(stepper.p) < sc.bed.settle_speed:
                return stepper.p, step
            if step >= max_steps:
                raise BedError(f"{sc.name}: the bed did not settle in {step} steps")


def machine() -> dict[str, Any]:
    """What a difference between machines may come from (information; never compared)."""
    import numba

    cpu: dict[str, str] = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            key = key.strip()
            if key in ("vendor_id", "model name", "cpu family", "model", "microcode") and key not in cpu:
                cpu[key] = value.strip()
            if key == "flags" and "flags" not in cpu:
                cpu["flags"] = " ".join(f for f in value.split() if f.startswith(("avx", "fma", "sse4")))
    except OSError:
        pass
    try:
        glibc = os.confstr("CS_GNU_LIBC_VERSION")
    except (ValueError, OSError, AttributeError):
        glibc = None
    try:
        import llvmlite.binding as llvm

        target = numba.config.CPU_NAME or llvm.get_host_cpu_name()
    except Exception:
        target = numba.config.CPU_NAME
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

        numpy_simd = [f for f in __cpu_dispatch__ if __cpu_features__.get(f)]
    except ImportError:
        numpy_simd = []
    return {
        "cpu": cpu,
        "platform": platform.platform(),
        "glibc": glibc,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numpy_simd": numpy_simd,
        "numba": numba.__version__,
        "numba_target": target,
        "numba_svml": bool(numba.config.USING_SVML),
    }


# ------------------------------------------------------------- correctly rounded
def _cr(d: Decimal) -> float:
    return float(d)  # a decimal string to the nearest double (correctly rounded)


def cr_log(x: float) -> float:
    with localcontext() as c:
        c.prec = 60
        return _cr(Decimal(x).ln())


def cr_sqrt(x: float) -> float:
    with localcontext() as c:
        c.prec = 60
        return _cr(Decimal(x).sqrt())


def cr_cos_sin(x: float) -> tuple[float, float]:
    """cos x, sin x correctly rounded (Taylor series in 80-digit decimals; |x| < 20)."""
    with localcontext() as c:
        c.prec = 80
        d = Decimal(x)
        term, cos, sin, k = Decimal(1), Decimal(0), Decimal(0), 0
        while True:
            if k % 2 == 0:
                cos += term if k % 4 == 0 else -term
            else:
                sin += term if k % 4 == 1 else -term
            k += 1
            term = term * d / k
            if k > 10 and abs(term) < Decimal(10) ** -75:
                break
        return _cr(cos), _cr(sin)


def cr_product(*factors: float) -> float:
    """The product of doubles taken left to right, each product correctly rounded to a
    double (fractions: exact, then rounded), as IEEE 754 multiplies."""
    out = Fraction(factors[0])
    for f in factors[1:]:
        out = Fraction(float(out * Fraction(f)))
    return float(out)


def correctly_rounded(cases: dict[str, Any], wheel_thetas: list[float]) -> list[dict[str, Any]]:
    """The set-up values against their correctly rounded values (decimal and fractions, no
    libm): the restitution's ln (exactmath), sqrt(5/6), each sphere's mass and inertia as
    exact operations in the model's order (``state.Particles.new``); one entry a constant
    (``ok``: bit-equal), arrays as counts. The lugs' cos and sin (detmath: within an ulp,
    not always correctly rounded) are counted as information."""
    from ooc_dem.physics import exactmath
    from ooc_dem.physics.d3 import contact as C3
    from ooc_dem.physics.layout import LUG_DIRECTION
    from ooc_dem.physics.wheel import lug_directions

    out: list[dict[str, Any]] = []

    def add(name: str, where: str, got: float, want: float) -> None:
        out.append(
            {
                "name": name,
                "kind": "constant",
                "where": where,
                "value": exact(got),
                "correct": exact(want),
                "ok": got == want,
            }
        )

    restitutions = sorted(
        {
            pair.restitution
            for sc in cases.values()
            for pair in (sc.contact.soil_soil, sc.contact.soil_wall, sc.contact.soil_wheel)
            if pair.law == "hertz" and 0.0 < pair.restitution < 1.0
        }
    )
    for e in restitutions:
        add(f"ln({e!r})", "physics/exactmath.py ln (beta_of_restitution)", exactmath.ln(e), cr_log(e))
    add("sqrt(5/6)", "physics/d3/contact.py SQRT_5_6", C3.SQRT_5_6, cr_sqrt(5.0 / 6.0))
    for label, sc in cases.items():
        fill = pinned_fill(sc)
        c = sc.soil.density * (4.0 / 3.0) * math.pi
        wrong = []
        for k in range(len(fill.r)):
            r = float(fill.r[k])
            mass = cr_product(c, cr_product(r, r, r))
            if fill.mass[k] != mass or fill.inertia[k] != cr_product(0.4, mass, r, r):
                wrong.append(k)
        out.append(
            {
                "name": f"mass, inertia of {label}'s fill ({len(fill.r)} spheres)",
                "kind": "array",
                "where": "model/state.py Particles.new (rho 4/3 pi (r r r), 0.4 m r r)",
                "wrong": len(wrong),
                "first_wrong": [exact(fill.r[k]) for k in wrong[:3]],
                "ok": not wrong,
            }
        )
    nlugs = cases[CASE].wheel.n_lugs
    lugdir = np.zeros(nlugs, LUG_DIRECTION)
    for theta in wheel_thetas:
        lug_directions(theta, nlugs, lugdir)
        wrong = []
        for k in range(nlugs):
            phi = theta + 2.0 * math.pi * k / nlugs  # as the kernel computes it
            cos, sin = cr_cos_sin(phi)
            if lugdir["ux"][k] != cos or lugdir["uy"][k] != sin:
                wrong.append(k)
        out.append(
            {
                "name": f"lug cos/sin at theta = {exact(theta)}",
                "kind": "step",
                "where": "physics/wheel.py lug_directions (detmath: within an ulp, the same bits everywhere)",
                "wrong": len(wrong),
                "first_wrong": [exact(theta + 2.0 * math.pi * k / nlugs) for k in wrong[:3]],
                "ok": not wrong,
            }
        )
    return out


# ------------------------------------------------------------------- the trace
def cached_bed(sc, bed) -> dict[str, Any]:
    """Whether this machine's bed cache holds the bed just settled (information: a cache
    made by other code, or on another machine, gives a run other bits)."""
    from ooc_dem.app.bed import bed_cache_path, read_bed

    path = bed_cache_path(sc)
    if not path.is_file():
        return {"path": str(path), "present": False}
    try:
        cached = read_bed(path, sc, "cached bed")
    except Exception as e:
        return {"path": str(path), "present": True, "error": str(e)}
    a, b = state_entries(cached), state_entries(bed)
    return {"path": str(path), "present": True, "differ": [k for k in b if a.get(k) != b[k]]}


def trace() -> dict[str, Any]:
    from ooc_dem.app.bed import _zero_motion, initial_fill, pour_scenario
    from ooc_dem.app.run_setup import place_wheel
    from ooc_dem.engine.stepper import DomainStepper, Model
    from ooc_dem.model.state import state_hash
    from ooc_dem.physics.layout import WS_THETA

    sc = scenario(CASE, [])
    cases = {CASE: sc}
    model = Model.from_scenario(sc)
    stages: list[dict[str, Any]] = [
        {"stage": f"constants {CASE}", "entries": model_entries(model)},
        {
            "stage": f"constants {CASE} settling",
            "entries": model_entries(Model.from_scenario(pour_scenario(sc)).without_wheel()),
        },
    ]
    fill = initial_fill(sc)
    stages.append({"stage": f"fill {CASE}", "entries": state_entries(fill)})
    for label, (name, sets) in OTHER.items():
        cases[label] = other = scenario(name, sets)
        stages.append({"stage": f"constants {label}", "entries": model_entries(Model.from_scenario(other))})
        stages.append({"stage": f"fill {label}", "entries": state_entries(pinned_fill(other))})
    settled, steps = settle_traced(sc, fill, stages)
    bed = _zero_motion(settled).sorted_by_id()
    stages.append({"stage": f"bed (settled in {steps} steps)", "entries": state_entries(bed)})
    cache = cached_bed(sc, bed)
    ws = place_wheel(sc, bed)
    stages.append({"stage": "wheel start", "entries": {**wheel_entries(ws), **lug_entries(ws, model)}})
    stepper = DomainStepper(bed, model, ws)
    step = 0
    for k in sorted(marks(RUN_CHECKPOINTS)):
        rec = stepper.advance(step, k - step)
        step = k
        stages.append(step_stage(f"run step {k}", stepper, model, rec[-1]))
    lugs: dict[str, str] = {}
    for theta in LUG_THETAS:
        lugs.update(
            {f"theta={exact(theta)} {k}": v for k, v in lug_entries(np.array([0, 0, 0, 0, theta, 0.0]), model).items()}
        )
    # last: the pinned run's wheel does not turn in its 3000 steps, a longer run's does
    stages.append({"stage": "lug directions (cos, sin)", "entries": lugs})
    return {
        "format": FORMAT,
        "case": {
            "scenario": CASE,
            "run_steps": RUN_STEPS,
            "settle_checkpoints": list(SETTLE_CHECKPOINTS),
            "run_checkpoints": list(RUN_CHECKPOINTS),
            "other": {k: " ".join([v[0], *(f"--set {s}" for s in v[1])]) for k, v in OTHER.items()},
        },
        "machine": machine(),
        # `ooc-dem run quick-3d --steps 3000`'s state_hash (test_kernel_bits.QUICK3D_3000)
        "state_hash": state_hash(stepper.p, stepper.ws, step),
        "stages": stages,
        "cached_bed": cache,
        "correctly_rounded": correctly_rounded(cases, sorted({*LUG_THETAS, float(stepper.ws[WS_THETA])})),
    }


def first_difference(want: dict[str, Any], got: dict[str, Any]) -> str | None:
    """None when got's stages are want's, else one message: the first stage that differs
    and every entry of it that does (a constant table's entries name its field)."""
    if want.get("format") != got.get("format") or want.get("case") != got.get("case"):
        return "the trace's format or case changed: regenerate the fixture (tools/trace_bits.py --write)"
    ws, gs = want["stages"], got["stages"]
    for k, (w, g) in enumerate(zip(ws, gs)):
        if w["stage"] != g["stage"]:
            return f"stage {k} is {g['stage']!r}, the fixture's {w['stage']!r}: regenerate the fixture"
        we, ge = w["entries"], g["entries"]
        differ = [n for n in we if we[n] != ge.get(n)] + [n for n in ge if n not in we]
        if differ:
            same = len(we) - len([n for n in differ if n in we])
            values = [
                f"{n} ({ge.get(n)} here, {we.get(n)} in the fixture)" if _scalar(we.get(n)) else n for n in differ
            ]
            later = sum(1 for w2, g2 in zip(ws[k + 1 :], gs[k + 1 :]) if w2["entries"] != g2["entries"])
            return (
                f"first difference at stage {g['stage']!r} (stage {k + 1} of {len(gs)}; "
                f"{len(ws) - k - 1 - later} later stages equal, {later} differ): "
                f"{len(differ)} entries differ: {', '.join(values)}; {same} equal"
            )
    if len(ws) != len(gs):
        return f"{len(gs)} stages, the fixture's {len(ws)}: regenerate the fixture"
    if want.get("state_hash") != got.get("state_hash"):
        return f"every stage equal, but the final state hash is {got.get('state_hash')}, the fixture's {want.get('state_hash')}"
    return None


def _scalar(v: str | None) -> bool:
    return v is not None and ("p" in v or v in ("inf", "-inf", "nan"))


def machine_line(m: dict[str, Any]) -> str:
    cpu = m.get("cpu", {})
    return (
        f"CPU {cpu.get('model name', '?')} ({cpu.get('vendor_id', '?')}, family {cpu.get('cpu family', '?')} "
        f"model {cpu.get('model', '?')}), {m.get('glibc')}, numpy {m.get('numpy')}, numba {m.get('numba')} "
        f"target {m.get('numba_target')} (SVML {m.get('numba_svml')}), numpy SIMD "
        f"{' '.join(m.get('numpy_simd', [])) or 'none'}, python {m.get('python')}"
    )


def rounding_line(t: dict[str, Any]) -> str:
    """The libm and numpy results a trace found not correctly rounded, in one line."""
    out = []
    for c in t.get("correctly_rounded", []):
        if c["ok"]:
            continue
        if c["kind"] == "constant":
            out.append(f"{c['name']} = {c['value']} (correct: {c['correct']})")
        else:
            libm = f", {c['not_libm']} not libm's" if "not_libm" in c else ""
            out.append(f"{c['name']}: {c['wrong']} wrong{libm}")
    return "; ".join(out) or "none"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--write", metavar="FILE", help="write the trace to FILE")
    ap.add_argument("--compare", metavar="FILE", help="compare with FILE's trace")
    args = ap.parse_args(argv)
    want = None
    if args.compare:
        try:
            want = json.loads(Path(args.compare).read_text())
        except (OSError, ValueError) as e:
            print(f"trace_bits: --compare {args.compare}: {e}", file=sys.stderr)
            return 2
    t = trace()
    text = json.dumps(t, indent=1) + "\n"
    if args.write:
        Path(args.write).write_text(text)
    elif not args.compare:
        sys.stdout.write(text)
    if want is not None:
        problem = first_difference(want, t)
        if problem:
            print(f"{problem}\nthis machine: {machine_line(t['machine'])}")
            print(f"  not correctly rounded: {rounding_line(t)}")
            print(f"{args.compare}'s machine: {machine_line(want.get('machine', {}))}")
            print(f"  not correctly rounded: {rounding_line(want)}")
            return 1
        print("the same bits at every stage")
    return 0


if __name__ == "__main__":
    sys.exit(main())
