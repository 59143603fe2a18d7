"""``ooc-dem animate``: a film of the soil flow from a run's trajectory (trajectory.py).

Each frame draws every disc in the colour of its initial horizontal layer (as the
deformation figure does: ``fields.layer_index`` over the initial heights), the wheel
(rim and lugs) at the frame's wheel state, and the time and the wheel's instantaneous
slip 1 - vx / (R omega) in the top-left corner. Frames are read, drawn and encoded one
at a time (memory: one frame plus the figure). MP4 (H.264) goes through ``imageio-ffmpeg``
(the ffmpeg binary ships in its wheel); GIF through Pillow (imageio's streaming GIF writer),
no ffmpeg needed. The file is written under a temporary name and renamed when complete.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ooc_dem.storage.writeguard import check_room

from .drawing import LAYER_COLOURS
from .runfiles import read_initial, read_run_scenario, run_file
from .trajectory import wheel_outline
from .trajectory_format import TrajectoryError
from .trajectory_read import Trajectory

if TYPE_CHECKING:
    from imageio.core.format import Format

FORMATS = (".mp4", ".gif")
MAX_FPS = 120
WIDTH_PX = 1280


def default_out(run_dir: str | os.PathLike[str]) -> Path:
    """RUN.mp4 beside the run directory (never inside the store)."""
    run_dir = Path(run_dir).resolve()
    return run_dir.parent / f"{run_dir.name}.mp4"


def _slip(ws: NDArray[np.float64], radius: float) -> float | None:
    rolled = -float(ws[5]) * radius  # wz < 0: the wheel turns clockwise, driving +x
    return 1.0 - float(ws[2]) / rolled if rolled > 1e-12 else None


def animate(
    run_dir: str | os.PathLike[str], out: str | os.PathLike[str] | None = None, fps: int = 20, progress: bool = False
) -> tuple[Path, int]:
    """Render the run's trajectory to ``out`` (.mp4 or .gif; default ``default_out``).
    Returns (the file, the number of frames)."""
    from .outfile import ExportError, check_targets
    from ..model.fields import layer_index
    from .drawing import layer_count, pyplot

    run_dir = Path(run_dir)
    out = Path(out) if out is not None else default_out(run_dir)
    ext = out.suffix.lower()
    if ext not in FORMATS:
        raise ExportError(f"--out {out}: give a .mp4 or .gif file name")
    if not 1 <= fps <= MAX_FPS:
        raise ExportError(f"--fps {fps}: must be in [1, {MAX_FPS}]")
    check_targets([out], out)
    if ext == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise ExportError(
                f"--out {out}: MP4 needs imageio-ffmpeg (pip install imageio-ffmpeg); a .gif needs no ffmpeg"
            ) from None
    import imageio.v2 as iio

    traj = Trajectory.of_run(run_dir)
    try:
        if len(traj) == 0:
            raise TrajectoryError(f"{traj.path}: no committed frame")
        if traj.dim != 2:
            raise TrajectoryError(f"{traj.path}: {traj.dim}D frames: animate draws 2D runs only")
        sc = read_run_scenario(run_dir)
        first = traj[0]
        x0, y0, r0 = first["pos"][:, 0], first["pos"][:, 1], first["r"]
        init = run_file(run_dir, "initial.npz")
        surface = (
            read_initial(init, len(first["id"]), sc)[4] if init is not None else float(np.max(y0 + r0, initial=0.0))
        )
        layer = layer_index(y0, surface, layer_count(surface, r0))
        from matplotlib.colors import to_rgba_array

        palette = to_rgba_array(list(LAYER_COLOURS) + ["#4a7fbf"])  # the layers, then "unknown disc"
        colour_of = (layer % 2).astype(np.int8)
        ids0 = first["id"]
        # the view: the bin (or the discs) from the floor to above the wheel's highest point
        if sc is not None:
            xa, xb = 0.0, sc.bin.length
        else:
            xa, xb = float(np.min(x0 - r0, initial=0.0)), float(np.max(x0 + r0, initial=1.0))
        ya = 0.0
        yb = max(surface, float(np.max(y0 + r0, initial=0.0)))
        wheel = sc.wheel if sc is not None and sc.wheel.enabled else None  # None: no wheel drawn
        if wheel is not None:
            yb = max(yb, float(np.max(traj.wheel_states[:, 1])) + wheel.lug_tip_radius)
        yb += 0.03 * (yb - ya)
        W = WIDTH_PX
        H = max(16, int(round(W * (yb - ya) / (xb - xa) / 16.0)) * 16)
        yb = ya + (xb - xa) * H / W  # equal scale in x and y
        plt = pyplot()
        dpi = 100
        fig = plt.figure(figsize=(W / dpi, H / dpi), dpi=dpi)
        ax = fig.add_axes([0, 0, 1, 1])
        ax.set_xlim(xa, xb)
        ax.set_ylim(ya, yb)
        ax.set_axis_off()
        ax.set_facecolor("white")
        from matplotlib.collections import EllipseCollection
        from matplotlib.patches import Polygon

        coll = None
        wpatch = Polygon(
            np.zeros((3, 2)),
            closed=True,
            facecolor="#b8c4d0",
            edgecolor="k",
            linewidth=0.8,
            zorder=5,
            visible=wheel is not None,
        )
        ax.add_patch(wpatch)
        label = ax.text(
            0.01,
            0.98,
            "",
            transform=ax.transAxes,
            va="top",
            ha="left",
            fontsize=14,
            family="monospace",
            zorder=10,
            bbox=dict(facecolor="white", edgecolor="0.5", alpha=0.85),
        )
        bar = None
        if progress:
            import sys
            from tqdm import tqdm

            bar = tqdm(total=len(traj), desc=f"animate {out.name}", unit="frame", file=sys.stderr, dynamic_ncols=True)

        def write(tmp: Path) -> int:
            nonlocal coll
            writer: _Ffmpeg | Format.Writer
            if ext == ".mp4":
                writer = _Ffmpeg(tmp, (W, H), fps)
            else:
                import imageio.plugins.pillow_legacy  # noqa: F401  (registers GIF-PIL)

                writer = iio.get_writer(tmp, format="GIF-PIL", mode="I", duration=1.0 / fps, loop=0)
            n = 0
            done = False
            try:
                for fr in traj:  # one frame at a time
                    ids, pos, r = fr["id"], fr["pos"], fr["r"]
                    if coll is None or len(ids) != len(np.asarray(coll.get_offsets())):
                        if coll is not None:
                            coll.remove()
                        at = np.clip(np.searchsorted(ids0, ids), 0, max(len(ids0) - 1, 0))
                        known = (ids0[at] == ids) if len(ids0) else np.zeros(len(ids), bool)
                        fc = palette[np.where(known, colour_of[at] if len(ids0) else 2, 2)]
                        d = 2.0 * r
                        coll = EllipseCollection(
                            d,
                            d,
                            np.zeros_like(d),
                            units="xy",
                            offsets=pos,
                            offset_transform=ax.transData,
                            facecolors=fc,
                            edgecolors="#3a2a1a",
                            linewidths=0.15,
                            zorder=1,
                        )
                        ax.add_collection(coll)
                    else:
                        coll.set_offsets(pos)
                    ws = fr["wheel_state"]
                    text = f"t = {fr['time']:7.3f} s"
                    if wheel is not None:
                        w = wheel
                        # the figures' time origin: travel time, 0 at the end of the wheel's settling
                        text = f"t = {fr['time'] - w.settle_time:7.3f} s of travel"
                        wpatch.set_xy(
                            wheel_outline(ws[0], ws[1], ws[4], w.radius, w.n_lugs, w.lug_tip_radius, w.lug_thickness)
                        )
                        s = _slip(ws, w.radius)
                        text += "\nslip = " + (f"{s:6.3f}" if s is not None else "   —  ")
                    label.set_text(text)
                    fig.canvas.draw()
                    img = np.asarray(fig.canvas.buffer_rgba())[:, :, :3]
                    writer.append_data(np.ascontiguousarray(img))
                    n += 1
                    if bar is not None:
                        bar.update(1)
                done = True
            finally:
                if isinstance(writer, _Ffmpeg):
                    writer.close(ok=done)  # raises if the encoder failed: no film is published
                else:
                    writer.close()
            return n

        # a floor of the film's size (H.264 ~15 kB a frame here, GIF ~130 kB): refused up front
        # only when surely too large; a failure while encoding is the encoder's exit status
        per_frame = 2048 if ext == ".mp4" else W * H // 32
        try:
            check_room(out, len(traj) * per_frame + 4096)
            n_written = _write_replacing_suffixed(out, write)
        except OSError as e:
            raise ExportError(f"--out {out}: cannot write ({e.strerror or e})") from None
        finally:
            if bar is not None:
                bar.close()
            plt.close(fig)
        return out, n_written
    finally:
        traj.close()


class _Ffmpeg:
    """H.264 MP4 through the ffmpeg binary of imageio-ffmpeg (the command imageio's FFMPEG
    writer runs), fed rgb24 frames on its stdin; unlike that writer, the encoder's exit
    status is checked, so a film it could not finish (a full disk, the file-size limit) is
    an error instead of a truncated file."""

    def __init__(self, path: Path, size: tuple[int, int], fps: int) -> None:
        import subprocess
        import threading
        import imageio_ffmpeg

        cmd = [
            imageio_ffmpeg.get_ffmpeg_exe(),
            "-y",
            "-f",
            "rawvideo",
            "-vcodec",
            "rawvideo",
            "-s",
            f"{size[0]}x{size[1]}",
            "-pix_fmt",
            "rgb24",
            "-r",
            str(int(fps)),
            "-i",
            "-",
            "-an",
            "-vcodec",
            "libx264",
            "-pix_fmt",
            "yuv420p",
            "-v",
            "error",
            "-f",
            "mp4",
            str(path),
        ]
        self.p = subprocess.Popen(
            cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True
        )
        if self.p.stdin is None or self.p.stderr is None:  # both are pipes (PIPE above)
            raise OSError("the encoder's stdin and stderr are not pipes")
        self._stdin, stderr = self.p.stdin, self.p.stderr
        self._err = b""
        self._broken = False

        def drain() -> None:  # its messages, kept short: the last one names the failure
            for line in stderr:
                self._err = (self._err + line)[-4096:]

        self._t = threading.Thread(target=drain, daemon=True)
        self._t.start()

    def append_data(self, img: NDArray[np.uint8]) -> None:
        try:
            self._stdin.write(np.ascontiguousarray(img).data.cast("B"))
        except (BrokenPipeError, ValueError):
            self._broken = True  # the encoder stopped: close() says why
            self.close()

    def close(self, ok: bool = True) -> None:
        """Finish the film and raise OSError if the encoder failed; ok=False (an error of
        our own is being reported): stop the encoder, raise nothing."""
        if self.p.returncode is None:
            try:
                self._stdin.close()
            except OSError:
                self._broken = True
            if not ok:
                self.p.kill()
            self.p.wait()
            self._t.join()
        rc = self.p.returncode
        if not ok or (rc == 0 and not self._broken):
            return
        lines = [ln.strip() for ln in self._err.decode("utf-8", "replace").splitlines() if ln.strip()]
        why = f": {lines[-1]}" if lines else ""
        if rc is not None and rc < 0:  # e.g. SIGXFSZ: subprocesses get the signal's default back
            import signal

            status = f"killed by {signal.Signals(-rc).name}"
        else:
            status = f"exit status {rc}"
        raise OSError(f"the encoder failed (ffmpeg {status}{why})")


def _write_replacing_suffixed(out: Path, write: Callable[[Path], int]) -> int:
    """atomic.write_replacing with a temporary that keeps the suffix (the encoders pick the
    format from it): created exclusively beside ``out``, renamed over it when complete."""
    import contextlib
    import os
    import tempfile

    fd, name = tempfile.mkstemp(prefix=f".{out.stem}.tmp-", suffix=out.suffix, dir=out.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        n = write(tmp)
        os.replace(tmp, out)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return n
