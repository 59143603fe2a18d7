"""The `ooc-dem` command line's arguments: the parser, its value types, and the one-line
usage errors (``CliError``, exit code 2). The modes offered come from ``engine.modes``."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import NoReturn

from ..errors import OocDemError

EXIT_USAGE = 2
EXIT_OOM = 137  # a profiled run killed by its --memory-limit (128 + SIGKILL, as a shell reports it)


class CliError(OocDemError):
    pass


def one_line(text: object) -> str:
    """A message on one line (a user error is one line on stderr)."""
    return " ".join(str(text).split())


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # one line, no usage dump
        print(f"ooc-dem: error: {message}{_suggestion(message)} (see `{self.prog} --help`)", file=sys.stderr)
        sys.exit(EXIT_USAGE)


def _suggestion(message: str) -> str:
    """'; did you mean ...?' for argparse's "invalid choice: 'x' (choose from 'a', 'b')"."""
    import ast
    import re

    from ..model.schema import did_you_mean

    m = re.search(r"invalid choice: (.*?) \(choose from (.*)\)$", message)
    if m is None:
        return ""
    try:
        word = ast.literal_eval(m.group(1))
        choices = ast.literal_eval(f"[{m.group(2)}]")
    except (ValueError, SyntaxError, MemoryError, RecursionError):
        return ""
    return did_you_mean(word, [str(c) for c in choices])


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{_show(text)} is not an integer") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"{_show(text)} must be >= 1")
    return v


def _nonneg_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{_show(text)} is not an integer") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"{_show(text)} must be >= 0")
    return v


def _show(text: object) -> str:
    from ..model.schema import show

    return show(text, 40)


def _count(lo: int, hi: int) -> Callable[[str], int]:
    """An integer flag in [lo, hi]; integral scientific notation (1e6) is accepted."""
    from decimal import Decimal, InvalidOperation
    from ..model.schema import big

    def parse(text: str) -> int:
        allowed = f"an integer in [{lo}, {big(hi)}]" if hi >= 10**6 else f"an integer in [{lo}, {hi}]"
        t = text.strip().replace("_", "")
        try:
            if len(t) > 40:  # also keeps int() clear of Python's digit limit
                raise InvalidOperation
            d = Decimal(t)
            if not d.is_finite() or d != d.to_integral_value():
                raise InvalidOperation
        except (InvalidOperation, ValueError):
            raise argparse.ArgumentTypeError(f"{_show(text)} is not {allowed}") from None
        if not lo <= d <= hi:
            raise argparse.ArgumentTypeError(f"{_show(text)} must be {allowed}")
        return int(d)

    return parse


def _size(text: str) -> int:
    """A memory size: 2GB, 1.5G, 512MiB, 300MB or bytes."""
    from ..engine.memlimit import parse_size

    try:
        return parse_size(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{_show(text)} is not a number") from None
    if not v > 0 or v != v or v == float("inf"):
        raise argparse.ArgumentTypeError(f"{_show(text)} must be a finite number > 0")
    return v


def _nonneg_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{_show(text)} is not a number") from None
    if not v >= 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"{_show(text)} must be a finite number >= 0")
    return v


def build_parser() -> argparse.ArgumentParser:
    from ..model.schema import MAX_BLOCK, MAX_DOMAINS, MAX_STEPS

    p = _Parser(
        prog="ooc-dem",
        description="Out-of-core 2D DEM of soil-wheel interaction (serial domain decomposition, bit-identical modes).",
    )
    from .. import __version__

    p.add_argument("--version", action="version", version=f"ooc-dem {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    from ..engine.modes import MODES, mode_names, switching_families

    def add_scenario_args(q: argparse.ArgumentParser) -> None:
        q.add_argument("scenario", help="built-in name (see `ooc-dem scenarios`) or a TOML file")
        q.add_argument(
            "--set",
            action="append",
            default=[],
            metavar="SECTION.KEY=VALUE",
            help="override a scenario value (repeatable)",
        )

    def add_plan_args(q: argparse.ArgumentParser) -> None:
        """The options `run` and `check` share (check validates them exactly as run would)."""
        q.add_argument(
            "--mode",
            default="monolithic",
            choices=mode_names(),
            help="; ".join(f"{m.name}: {m.summary}" for m in MODES.values()) + " (the MPI modes under mpiexec)",
        )
        q.add_argument(
            "--backend",
            default="hdf5",
            choices=["hdf5", "zarr", "memory"],
            help="memory: the store lives only in this process (no resume); summary, "
            "series and figures are still written to --out",
        )
        q.add_argument(
            "--compression",
            default="none",
            choices=["none", "zstd", "blosc", "gzip", "lzf"],
            help="compress the store's arrays: zarr zstd|blosc, hdf5 gzip|lzf (default "
            "none: see docs/format.md, Disk economy)",
        )
        q.add_argument(
            "--io-overlap",
            action="store_true",
            help="out-of-core: read the next slab and write the last one in threads while a "
            "slab computes (same bits; up to three slabs resident)",
        )
        q.add_argument("--domains", type=_count(1, MAX_DOMAINS), help="number of sub-domains D (ddm, ooc)")
        q.add_argument("--block", type=_count(1, MAX_BLOCK), help="steps per epoch K (temporal blocking)")
        g = q.add_mutually_exclusive_group()
        g.add_argument("--steps", type=_count(0, MAX_STEPS), help="total steps to run")
        g.add_argument("--duration", type=_positive_float, help="total simulated time to run, s")
        q.add_argument(
            "--checkpoint-every", type=_count(1, MAX_STEPS), metavar="STEPS", help="commit an epoch every STEPS steps"
        )
        q.add_argument(
            "--memory",
            type=_size,
            metavar="SIZE",
            help="memory budget, e.g. 2GB: out-of-core chooses the sub-domains D and "
            "block K whose slab, halo and I/O buffers fit; other modes are checked "
            "against it",
        )

    q = sub.add_parser("run", help="run a scenario")
    add_scenario_args(q)
    q.add_argument("--out", required=False, help="output directory (a new store); default runs/<scenario>")
    add_plan_args(q)
    q.add_argument("--durable", action="store_true", help="fsync files and directory before each commit")
    q.add_argument("--bed", help="a prepared bed directory (from `ooc-dem prepare`)")
    q.add_argument("--no-progress", action="store_true")
    q.add_argument("--no-figures", action="store_true")

    q = sub.add_parser("prepare", help="generate and settle the scenario's bed")
    add_scenario_args(q)
    q.add_argument("--out", required=True, help="directory for the settled bed")
    q.add_argument("--no-progress", action="store_true")

    q = sub.add_parser("resume", help="continue a killed or finished run from its last committed epoch")
    q.add_argument("store")
    g = q.add_mutually_exclusive_group()
    g.add_argument("--steps", type=_count(0, MAX_STEPS), help="new total step count")
    g.add_argument("--until", type=_positive_float, help="new total simulated time, s")
    switching = switching_families()
    q.add_argument(
        "--mode",
        choices=[name for family in switching for name in family],
        help="continue in another mode of those that share their epochs: "
        + ", ".join(" or ".join(f) for f in switching),
    )
    q.add_argument("--no-progress", action="store_true")
    q.add_argument("--no-figures", action="store_true")

    q = sub.add_parser("checkpoint", help="list, verify, inspect, prune and export the epochs of a store")
    csub = q.add_subparsers(dest="ckpt_command", required=True, parser_class=_Parser)
    for name, hlp in (
        ("hash", "the canonical state hash (mset-v2) of the latest state"),
        ("list", "list committed epochs"),
        ("verify", "verify checksums and structure (exit 2 if a problem is found)"),
        ("inspect", "show one epoch"),
    ):
        c = csub.add_parser(name, help=hlp)
        c.add_argument("store")
        if name != "list":
            c.add_argument("--epoch", type=_nonneg_int, help="epoch step (default: current)")
    c = csub.add_parser("prune", help="delete committed epochs beyond the newest N (never the current)")
    c.add_argument("store")
    c.add_argument(
        "--keep",
        type=_positive_int,
        required=True,
        metavar="N",
        help="number of newest committed epochs to keep (>= 1; the current is always kept)",
    )
    c = csub.add_parser("export", help="write one epoch as XDMF+HDF5, VTK or CSV")
    c.add_argument("store")
    c.add_argument(
        "--format",
        choices=["xdmf", "vtk", "csv"],
        help="xdmf (NAME.xdmf + NAME.h5), vtk (legacy ASCII .vtk, or VTK XML if --out ends in "
        ".vtu or .vtp) or csv; default from the --out suffix",
    )
    c.add_argument("--out", required=True, metavar="FILE", help="output file")
    c.add_argument("--epoch", type=_nonneg_int, help="epoch step (default: current)")

    q = sub.add_parser(
        "export-trajectory",
        help="write a run's trajectory as XDMF 3 time series (+ HDF5) for ParaView and meshio: "
        "FILE.xdmf the particles, FILE-wheel.xdmf the wheel's surface",
    )
    q.add_argument("run", metavar="RUN", help="run directory (with trajectory/)")
    q.add_argument("--out", required=True, metavar="FILE.xdmf", help="XDMF file to write (outside the run)")

    q = sub.add_parser("animate", help="render a run's trajectory as a film (MP4 or GIF)")
    q.add_argument("run", metavar="RUN", help="run directory (with trajectory/)")
    q.add_argument(
        "--out",
        metavar="FILE",
        help="FILE.mp4 (ffmpeg from imageio-ffmpeg) or FILE.gif; default RUN.mp4 beside the run directory",
    )
    q.add_argument("--fps", type=_count(1, 120), default=20, help="frames per second (default 20)")
    q.add_argument(
        "--colour",
        choices=["speed", "height"],
        default="speed",
        help="3D runs: colour the spheres by their speed or their height (2D runs keep their layer colours)",
    )
    q.add_argument("--no-progress", action="store_true")

    q = sub.add_parser("scenarios", help="list built-in scenarios")
    q.add_argument(
        "--show",
        metavar="NAME",
        help="print the resolved scenario NAME (a built-in or a file) as a complete TOML, "
        "every key commented with its unit and meaning",
    )

    q = sub.add_parser(
        "check",
        help="validate a scenario and run options as `run` would; print the "
        "resolved plan as JSON (no files, no bed, no stepping)",
    )
    add_scenario_args(q)
    add_plan_args(q)

    q = sub.add_parser(
        "report",
        help="regenerate figures and print the wheel-performance table (of a run, or the drawbar pull - "
        "slip curve of a sweep; several sweeps: overlaid in one figure)",
    )
    q.add_argument("store", nargs="+", metavar="DIR", help="a run's or a sweep's directory; or several sweeps'")
    q.add_argument(
        "--out", default=None, metavar="PNG", help="several sweeps: the overlay figure's file (required with them)"
    )
    q.add_argument(
        "--formats",
        default="",
        metavar="pdf,svg",
        help="also write every figure in these formats (pdf, svg), beside its PNG",
    )

    q = sub.add_parser("compare", help="compare two runs (Table 3 style) and their final states")
    q.add_argument("a")
    q.add_argument("b")

    q = sub.add_parser("profile", help="peak RSS of each mode (fresh subprocess each) against monolithic")
    add_scenario_args(q)
    profiled = ",".join(mode_names(lambda m: not m.mpi))
    q.add_argument("--modes", default=profiled, help=f"comma-separated: {profiled}")
    q.add_argument("--out", required=True, help="directory for memory.json, memory.md, memory.png")
    q.add_argument("--domains", type=_count(1, MAX_DOMAINS))
    q.add_argument("--block", type=_count(1, MAX_BLOCK))
    q.add_argument("--backend", default="hdf5", choices=["hdf5", "zarr"])
    q.add_argument("--steps", type=_count(1, MAX_STEPS), default=200, help="steps measured per mode")
    q.add_argument(
        "--memory-limit",
        type=_size,
        metavar="SIZE",
        help="run each mode under this hard memory limit (a memory cgroup made for it, "
        "removed after; needs root or a delegated cgroup); a mode that exceeds it is "
        f"reported as killed by the limit, exit code {EXIT_OOM}",
    )

    q = sub.add_parser(
        "shear", help="direct shear box test of the scenario's soil: peak and residual strength, Mohr-Coulomb c and phi"
    )
    add_scenario_args(q)
    q.add_argument(
        "--sigma", default="5e3,10e3,20e3", help="comma-separated normal stresses in Pa (default 5e3,10e3,20e3)"
    )
    q.add_argument("--grains", type=_nonneg_int, default=0, help="grains in the box (default: the scenario's soil.n)")
    q.add_argument(
        "--inertial",
        type=_positive_float,
        default=1e-3,
        help="inertial number aimed at the smallest stress; sets the shear speed (default 1e-3)",
    )
    q.add_argument("--speed", type=_positive_float, default=None, help="shear speed in m/s (instead of --inertial)")
    q.add_argument(
        "--displacement",
        type=_positive_float,
        default=0.10,
        help="shear displacement as a fraction of the box's length (default 0.10)",
    )
    q.add_argument("--out", required=True)
    q.add_argument("--no-figures", action="store_true")
    q.add_argument("--no-progress", action="store_true")

    q = sub.add_parser(
        "calibrate",
        help="calibrate the scenario's soil to a lab sheet (friction angle, cohesion, bulk density) "
        "with pours and shear box tests; writes the scenario fragment",
    )
    add_scenario_args(q)
    q.add_argument("--friction-angle", type=_positive_float, required=True, help="target friction angle in degrees")
    q.add_argument("--cohesion", type=_nonneg_float, default=0.0, help="target cohesion in Pa (default 0)")
    q.add_argument(
        "--bulk-density", type=_nonneg_float, default=0.0, help="target bulk density in kg/m^3 (default: not a target)"
    )
    q.add_argument(
        "--sigma", default="3e3,6e3,9e3,12e3", help="the shear tests' normal stresses in Pa (default 3e3,6e3,9e3,12e3)"
    )
    q.add_argument("--grains", type=_nonneg_int, default=2000, help="grains in the shear box (default 2000)")
    q.add_argument("--envelope", choices=["peak", "residual"], default="peak", help="the envelope calibrated")
    q.add_argument(
        "--vary",
        choices=["friction", "rolling_friction"],
        default="friction",
        help="the soil-soil value searched for the friction angle (default friction)",
    )
    q.add_argument("--evaluations", type=_nonneg_int, default=8, help="shear tests at most")
    q.add_argument("--out", required=True)
    q.add_argument("--no-progress", action="store_true")

    q = sub.add_parser(
        "sinkage", help="plate sinkage test of the scenario's bed: pressure-sinkage curves, Bekker k_c, k_phi and n"
    )
    add_scenario_args(q)
    q.add_argument(
        "--widths", default="", help="comma-separated plate widths in m (default: 1/4 and 1/2 of the bed depth)"
    )
    q.add_argument(
        "--depth", type=_positive_float, default=None, help="final sinkage in m (default: 1/5 of the bed depth)"
    )
    q.add_argument("--speed", type=_positive_float, default=0.01, help="the plate's speed in m/s (default 0.01)")
    q.add_argument("--out", required=True)
    q.add_argument("--no-figures", action="store_true")
    q.add_argument("--no-progress", action="store_true")

    q = sub.add_parser("sweep", help="drawbar pull - slip curve (slip-controlled runs)")
    add_scenario_args(q)
    q.add_argument(
        "--slips",
        required=True,
        help="comma-separated slips in [-1, 1), e.g. 0.1,0.2,0.4 (negative: braking; write --slips=-0.2,0.1)",
    )
    q.add_argument(
        "--out",
        required=True,
        help="a new directory, or an existing sweep of the same scenario and --set to add slips to "
        "(its finished runs reused)",
    )
    q.add_argument("--no-progress", action="store_true")

    q = sub.add_parser(
        "experiment",
        help="a single-wheel testbed experiment end to end: calibrate the soil from its lab properties, "
        "run every wheel's slips (resumable), compare with the measured points",
    )
    q.add_argument("file", metavar="FILE", help="the experiment file (docs/reference/experiment.md)")
    q.add_argument("--out", required=True, help="output directory; run the command again on it to continue")
    q.add_argument("--only", action="append", default=[], metavar="WHEEL", help="only this wheel (repeatable)")
    q.add_argument("--slips", default="", help="comma-separated subset of the file's slips")
    q.add_argument(
        "--plan", action="store_true", help="check the file and print the model and its runs as JSON (nothing run)"
    )
    q.add_argument("--no-progress", action="store_true")
    return p
