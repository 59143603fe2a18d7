"""The Python API: the CLI's ``run``, ``resume`` and store reading as functions returning objects.

Everything here goes through the code the CLI uses (``scenario.load_scenario``,
``engine.run.Simulation`` / ``resume_simulation``, ``storage.open_store``, the checkpoint
validators), so a scenario, a run option or a store is accepted or refused exactly as
``ooc-dem`` would, with the same one-line message - raised as a typed exception
(``ScenarioError``, ``RunError``, ``StoreError``, ``StateError``, ...) instead of an exit.

Progress bars are off unless asked for (``progress=True``); figures are not drawn unless
asked for (``figures=True``; ``ooc-dem report RUN`` draws them later).
"""

from __future__ import annotations

import numbers
import os
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np
    import pandas as pd
    from numpy.typing import NDArray

    from .app.trajectory_read import Trajectory
    from .model.scenario import Scenario
    from .storage import Store

__all__ = ["load_scenario", "run", "resume", "open_run", "open_store", "RunResult"]


# ------------------------------------------------------------------ scenarios


def _override_items(overrides: Mapping[Any, object], prefix: str = "") -> Iterator[str]:
    """``section.key=value`` items (the text ``--set`` takes) from a mapping of overrides.

    ``{"wheel.slip": 0.3}`` and ``{"wheel": {"slip": 0.3}}`` give ``wheel.slip=0.3``; values are
    written as TOML (the CLI parses ``--set`` values as TOML), so they are parsed, coerced and
    range-checked by the same code as ``--set``.
    """
    from .model.schema import ScenarioError, show, toml_string

    for key, value in overrides.items():
        if not isinstance(key, str):
            raise ScenarioError(f"overrides key {show(key)}: must be a string such as 'wheel.slip'")
        full = f"{prefix}.{key}" if prefix else key
        if "=" in key or not key.strip():
            raise ScenarioError(f"overrides key {show(full)}: must be section.key (e.g. 'physics.dt')")
        if isinstance(value, Mapping):
            yield from _override_items(value, full)
            continue
        if isinstance(value, bool):
            text = "true" if value else "false"
        elif isinstance(value, numbers.Integral):
            text = str(int(value))
        elif isinstance(value, numbers.Real):
            text = repr(float(value))  # inf and nan are TOML too: refused as "must be finite"
        elif isinstance(value, str):
            text = toml_string(value)
        elif isinstance(value, (list, tuple)) and all(
            isinstance(x, numbers.Real) and not isinstance(x, bool) for x in value
        ):  # an array of numbers (soil.grading.sizes, soil.grading.passing)
            text = (
                "[" + ", ".join(str(int(x)) if isinstance(x, numbers.Integral) else repr(float(x)) for x in value) + "]"
            )
        else:
            raise ScenarioError(
                f"{full} = {show(value)}: must be a number, a string, true/false or an array of numbers"
            )
        yield f"{full}={text}"


def load_scenario(
    name_or_path: str | os.PathLike[str], overrides: Mapping[str, object] | Iterable[str] | None = None
) -> Scenario:
    """Load and validate a scenario: a built-in name or the path of a TOML file.

    Parameters
    ----------
    name_or_path : str or os.PathLike
        ``"quick"``, ``"paper2008"``, ``"bed-100k"`` (see ``ooc-dem scenarios``) or a TOML file;
        a file may start with ``base = "quick-3d"`` and hold only what it changes
        (docs/parameters.md lists every key).
    overrides : mapping or list of str, optional
        Values replacing the scenario's, as ``{"wheel.slip": 0.3}``, nested as
        ``{"wheel": {"slip": 0.3}, "contact": {"soil_soil": {"kn": 1e5}}}``, or as the CLI's
        ``["wheel.slip=0.3"]``. Checked exactly as ``ooc-dem run --set`` checks them.

    Returns
    -------
    Scenario
        A frozen dataclass (``sc.wheel.slip``, ``sc.physics.dt``, ``sc.to_toml()``, ``sc.hash()``).

    Raises
    ------
    ScenarioError
        Unknown scenario, unreadable file, unknown key, wrong type or out-of-range value; the
        message is one line naming the key, the value and what is allowed.
    """
    from .model.scenario import ScenarioError, load_scenario as _load

    if overrides is None:
        items = []
    elif isinstance(overrides, Mapping):
        items = list(_override_items(overrides))
    elif isinstance(overrides, (str, bytes)):
        raise ScenarioError(
            "overrides: must be a mapping such as {'wheel.slip': 0.3} or a list of 'section.key=value' strings"
        )
    else:
        items = list(overrides)
        if not all(isinstance(i, str) for i in items):
            raise ScenarioError("overrides: a list of overrides must hold 'section.key=value' strings")
    source = os.fspath(name_or_path) if isinstance(name_or_path, os.PathLike) else name_or_path
    try:
        return _load(source, items)
    except ScenarioError as e:
        msg = str(e)
        if msg.startswith("--set "):  # the same message, naming this function's parameter
            raise ScenarioError("override " + msg[len("--set ") :]) from None
        raise


def _scenario(
    scenario: Scenario | str | os.PathLike[str], overrides: Mapping[str, object] | Iterable[str] | None
) -> Scenario:
    from .model.scenario import Scenario

    if isinstance(scenario, Scenario):
        if overrides:
            from .model.scenario import ScenarioError

            raise ScenarioError(
                "overrides: give them to load_scenario(); run() takes them only with a scenario name or file"
            )
        return scenario
    return load_scenario(scenario, overrides)


# ------------------------------------------------------------------- results


class RunResult:
    """The outputs of a run directory: summary, time series and the state of its epochs.

    Attributes
    ----------
    path : pathlib.Path
        The run directory (the store plus ``summary.json``, ``series.csv``, ...).

    Everything is read from the directory when asked for (the summary and the series once,
    then kept), so a ``RunResult`` of a run made by ``ooc-dem run`` works the same
    (``open_run(path)``).
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._summary: dict[str, Any] | None = None
        self._series: NDArray[np.void] | None = None

    def __repr__(self) -> str:
        return f"RunResult({str(self.path)!r})"

    @property
    def summary(self) -> dict[str, Any]:
        """``summary.json`` as a dict: ``slip``, ``net_traction``, ... (each with its ``unit``,
        ``whole_travel`` and ``steady`` windows), ``steps``, ``state_hash``, ``wall_time_s``.

        Raises RunFileError if the run has no (valid) summary (not finished)."""
        if self._summary is None:
            from .app.runfiles import RunFileError, read_summary

            summary = read_summary(self.path)
            if summary is None:  # read_summary raises for a finished run's missing summary
                raise RunFileError(f"{self.path}: no summary.json (not a finished ooc-dem run)")
            self._summary = summary
        return self._summary

    @property
    def series(self) -> NDArray[np.void]:
        """``series.csv`` as a NumPy structured array, one field per column (``t``, ``t_travel``,
        ``x``, ``y``, ``vx``, ``omega``, ``slip``, ``net_traction``, ``vertical_force``,
        ``torque``, ``gross_traction``, ``sinkage``, ``drawbar``; SI units as in the CSV header).

        A run without a wheel has no series: a structured array of length 0 with those fields.
        Raises RunFileError if the file is unreadable or not ooc-dem's."""
        if self._series is None:
            import numpy as np
            from .app.metrics import SERIES_COLUMNS
            from .app.runfiles import read_series, run_file

            f = run_file(self.path, "series.csv")
            cols = read_series(f) if f is not None else {c: np.zeros(0) for c in SERIES_COLUMNS}
            names = list(cols)
            n = len(cols[names[0]]) if names else 0
            arr = np.zeros(n, dtype=[(c, "<f8") for c in names])
            for c in names:
                arr[c] = cols[c]
            self._series = arr
        return self._series

    def series_frame(self) -> pd.DataFrame:
        """The series as a ``pandas.DataFrame`` (ImportError naming pandas if it is not installed)."""
        try:
            import pandas as pd
        except ImportError:
            raise ImportError(
                "RunResult.series_frame() / to_pandas() needs pandas "
                "(pip install pandas); RunResult.series is the same table as a "
                "NumPy structured array"
            ) from None
        return pd.DataFrame.from_records(self.series)

    to_pandas = series_frame

    def trajectory(self) -> Trajectory:
        """The run's trajectory frames (``output.snapshot_interval``), read from
        ``trajectory/`` (one HDF5 file a frame) one at a time.

        Returns
        -------
        Trajectory
            A sequence: ``len(t)`` committed frames, ``t[i]`` (and iteration) gives a dict of
            NumPy arrays sorted by disc id (``id``, ``pos`` (N, D), ``vel``, ``spin``, ``r``,
            ``mat``) plus ``step``, ``time`` and ``wheel_state``; ``t.steps``, ``t.times`` and
            ``t.wheel_states`` are the frame index. Use it as a context manager (or call
            ``close()``) to release the file.

        Raises
        ------
        TrajectoryError
            The run wrote no trajectory, or the file is unreadable or not ooc-dem's
            (a ``RunFileError``).
        """
        from .app.trajectory_read import Trajectory

        return Trajectory.of_run(self.path)

    def epochs(self) -> list[int]:
        """Steps of the committed epochs in the store (oldest first); a run keeps its last two."""
        with open_store(self.path) as store:
            return store.epochs()

    def state(self, epoch: int | None = None) -> dict[str, NDArray[Any]]:
        """The discs of one committed epoch as a dict of NumPy arrays, sorted by disc id.

        Parameters
        ----------
        epoch : int, optional
            The epoch's step (see ``epochs()``); default the current (last committed) one,
            or the previous if the current fails verification, as ``ooc-dem resume`` would.

        Returns
        -------
        dict
            One array per state field (as in the store: ``id``, positions, velocities, spin,
            ``r``, ``mass``, ``inertia``, ``mat``, contact history), row i = the disc of the
            i-th smallest id. Equal arrays (``np.array_equal``) mean the same state bits.

        Raises
        ------
        StoreError
            No such epoch in the store, or the store is missing, foreign or corrupt.
        StateError
            The epoch's checksums pass but it holds a state this engine could not have written.
        """
        from .model.checkpoint import read_epoch_particles

        with open_store(self.path) as store:
            particles, _, _ = read_epoch_particles(store, str(self.path), epoch)
        return dict(particles.arrays())


# ----------------------------------------------------------------------- runs


def run(
    scenario: Scenario | str | os.PathLike[str],
    out: str | os.PathLike[str] | None = None,
    mode: str = "monolithic",
    domains: int | None = None,
    block: int | None = None,
    backend: str = "hdf5",
    steps: int | None = None,
    duration: float | None = None,
    progress: bool = False,
    *,
    overrides: Mapping[str, object] | Iterable[str] | None = None,
    checkpoint_every: int | None = None,
    durable: bool = False,
    figures: bool = False,
    bed: str | os.PathLike[str] | None = None,
    compression: str | None = None,
) -> RunResult:
    """Run a scenario to the end, as ``ooc-dem run`` does, and return its ``RunResult``.

    Parameters
    ----------
    scenario : Scenario, str or os.PathLike
        A scenario from ``load_scenario``, or a built-in name / TOML file (loaded with
        ``overrides``).
    out : path, optional
        Output directory, a new (or empty) one; default ``runs/<scenario name>`` (relative to
        the current directory, as the CLI). With ``backend="memory"`` the store lives in this
        process only; ``summary.json`` and ``series.csv`` are still written to ``out``.
    mode : {"monolithic", "ddm", "ooc"}
        Execution mode; all three give the same bits.
    domains, block : int, optional
        Sub-domains D and steps per epoch K (``ddm``, ``ooc``); default from the scenario.
    backend : {"hdf5", "zarr", "memory"}
        The store's backend.
    steps, duration : optional
        Total steps, or total simulated time in s (not both); default the scenario's
        settle + travel time (bare beds: ``output.run_steps``).
    progress : bool
        Show the progress bar on stderr (off by default here; on in the CLI).
    overrides : mapping, optional
        Scenario overrides (as ``load_scenario``) when ``scenario`` is a name or file.
    checkpoint_every : int, optional
        Steps between committed epochs (the CLI's ``--checkpoint-every``).
    durable : bool
        fsync each commit (``--durable``).
    figures : bool
        Draw ``figures/*.png`` at the end (off by default; ``ooc-dem report`` draws them).
    bed : path, optional
        A prepared bed directory from ``ooc-dem prepare`` (``--bed``).
    compression : str, optional
        Compress the store's arrays (``--compression``): ``"zstd"`` or ``"blosc"`` (zarr),
        ``"gzip"`` or ``"lzf"`` (hdf5); default none. Kept by ``resume``.

    Returns
    -------
    RunResult

    Raises
    ------
    ScenarioError, RunError, StoreError, StateError, EngineError, BedError
        With the one-line message the CLI would print. The store is released on any error or
        KeyboardInterrupt: the last committed epoch is kept and ``resume(out)`` continues.
    """
    from .app.plan import RunOptions
    from .app.run import Simulation

    if steps is not None and duration is not None:
        from .app.plan import RunError

        raise RunError("steps and duration: give one of them, not both")
    sc = _scenario(scenario, overrides)
    out = Path(out) if out is not None else Path("runs") / sc.name
    opts = RunOptions(
        mode=mode,
        backend=backend,
        domains=domains,
        block=block,
        steps=steps,
        duration=duration,
        checkpoint_every=checkpoint_every,
        durable=durable,
        progress=progress,
        figures=figures,
        compression=compression,
    )
    sim = Simulation(sc, out, opts)  # plans and checks everything before a file is written
    prepared = None
    if bed is not None:
        from .app.cli_commands import load_bed
        from .app.cli_parser import CliError
        from .app.plan import RunError

        try:
            prepared = load_bed(bed, sc)
        except CliError as e:  # the CLI's checks of a prepared bed, raised as a RunError
            raise RunError(str(e).replace("--bed ", "bed ", 1)) from None
    try:
        sim.start(prepared, streamed=True)
        sim.run()
    finally:
        sim.close()  # the write lock is released whatever happened
    return RunResult(out)


def resume(
    path: str | os.PathLike[str],
    steps: int | None = None,
    until: float | None = None,
    progress: bool = False,
    figures: bool = False,
) -> RunResult:
    """Continue a killed (or finished) run from its last committed epoch, as ``ooc-dem resume``.

    The resumed run ends with the same bits as one that was never interrupted.

    Parameters
    ----------
    path : path
        The run directory.
    steps, until : optional
        A new total step count, or a new total simulated time in s (not both); default the
        run's own.
    progress, figures : bool
        As for ``run``.

    Returns
    -------
    RunResult
        Also when the run had already finished (then its missing outputs, if any, are written).

    Raises
    ------
    RunError, StoreError, StateError, ScenarioError
        Not a run, another process writes it, damaged store, ... (one-line message).
    """
    from .app.plan import RunError
    from .app.run import resume_simulation

    if steps is not None and until is not None:
        raise RunError("steps and until: give one of them, not both")
    sim = resume_simulation(path, steps=steps, until=until, progress=progress, figures=figures)
    if sim is None:
        return RunResult(path)
    try:
        sim.run()
    finally:
        sim.close()
    return RunResult(path)


def open_run(path: str | os.PathLike[str]) -> RunResult:
    """The ``RunResult`` of an existing run directory (e.g. one made by ``ooc-dem run``).

    Nothing is read until asked for; ``summary``, ``series`` and ``state()`` raise as
    documented there if the directory is not a (finished) run."""
    p = Path(path)
    if not p.is_dir():
        from .app.runfiles import RunFileError

        raise RunFileError(f"{p}: not a directory")
    return RunResult(p)


def open_store(path: str | os.PathLike[str]) -> Store:
    """Open a run's store read-only (``storage.Store``): no lock, nothing deleted or written.

    Works while a run writes it. Use as a context manager, or ``close()`` it. Useful calls:
    ``epochs()``, ``current()``, ``list_epochs()``, ``verify(step)``, ``read_epoch(step)`` (an
    ``EpochReader``: ``domains()``, ``read_domain(d)``, ``read_globals()``, ``close()``);
    ``begin_epoch`` and ``prune`` raise StoreError.

    Raises StoreError if ``path`` is not an ooc-dem store (one line naming the problem).
    """
    from ooc_dem.storage import open_store as _open

    return _open(path, repair=False)
