"""``ooc-dem animate``: a film of the soil flow from a run's trajectory (trajectory.py).

2D: each frame draws every disc in the colour of its initial horizontal layer (as the
deformation figure does: ``fields.layer_index`` over the initial heights), the wheel
(rim and lugs) at the frame's wheel state, and the time and the wheel's instantaneous
slip 1 - vx / (R omega) in the top-left corner. 3D: two panels, the side view of the bed
and a cut at the wheel's mid-plane, the spheres splatted into pictures with numpy
(film3d.py: a z-buffer, no artist per sphere) coloured by speed or height, the wheel's
outline over them, and the same corner label (``Scene3D``). Frames are read, drawn and encoded one
at a time (memory: one frame plus the figure). MP4 (H.264) goes through ``imageio-ffmpeg``
(the ffmpeg binary ships in its wheel); GIF through Pillow (imageio's streaming GIF writer),
no ffmpeg needed. The file is written under a temporary name and renamed when complete.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ooc_dem.storage.writeguard import check_room

from .drawing import LAYER_COLOURS
from .film3d import SphereSplatter, colour_map
from .runfiles import read_initial, read_run_scenario, run_file
from .trajectory import wheel_outline
from .trajectory_format import TrajectoryError
from .trajectory_read import Frame, Trajectory
from .wheel_surface import WheelGeometry, mesh_at_pose

if TYPE_CHECKING:
    from imageio.core.format import Format
    from matplotlib.axes import Axes
    from matplotlib.collections import EllipseCollection
    from matplotlib.patches import Polygon
    from matplotlib.text import Text

    from ..model.scenario import Scenario
    from ..model.schema import Wheel

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


COLOURINGS = ("speed", "height")  # 3D runs' sphere colours


def animate(
    run_dir: str | os.PathLike[str],
    out: str | os.PathLike[str] | None = None,
    fps: int = 20,
    progress: bool = False,
    colour: str = "speed",
) -> tuple[Path, int]:
    """Render the run's trajectory to ``out`` (.mp4 or .gif; default ``default_out``): a 2D
    run's discs in their layer colours, a 3D run's spheres as a side view and a cut at the
    wheel's mid-plane (``Scene3D``), coloured by ``colour`` (speed or height).
    Returns (the file, the number of frames)."""
    from .outfile import ExportError, check_targets

    run_dir = Path(run_dir)
    out = Path(out) if out is not None else default_out(run_dir)
    ext = out.suffix.lower()
    if ext not in FORMATS:
        raise ExportError(f"--out {out}: give a .mp4 or .gif file name")
    if not 1 <= fps <= MAX_FPS:
        raise ExportError(f"--fps {fps}: must be in [1, {MAX_FPS}]")
    if colour not in COLOURINGS:
        raise ExportError(f"--colour {colour!r}: must be one of {', '.join(COLOURINGS)}")
    check_targets([out], out)
    if ext == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise ExportError(
                f"--out {out}: MP4 needs imageio-ffmpeg (pip install imageio-ffmpeg); a .gif needs no ffmpeg"
            ) from None

    traj = Trajectory.of_run(run_dir)
    try:
        if len(traj) == 0:
            raise TrajectoryError(f"{traj.path}: no committed frame")
        sc = read_run_scenario(run_dir)
        scene: Scene2D | Scene3D = Scene2D(traj, sc, run_dir) if traj.dim == 2 else Scene3D(traj, sc, colour)
        return out, _film(traj, scene, out, fps, progress)
    finally:
        traj.close()


def _view_top(traj: Trajectory, wheel: Wheel | None, top: float) -> float:
    """The view's top: above the soil (``top``) and the wheel's highest point over the run."""
    if wheel is not None:
        top = max(top, float(np.max(traj.wheel_states[:, 1])) + wheel.lug_tip_radius)
    return top


def _frame_label(fr: Frame, wheel: Wheel | None) -> str:
    """The corner label: the time (a wheel run's travel time, 0 at the end of its settling)
    and the wheel's instantaneous slip."""
    if wheel is None:
        return f"t = {fr['time']:7.3f} s"
    s = _slip(fr["wheel_state"], wheel.radius)
    return f"t = {fr['time'] - wheel.settle_time:7.3f} s of travel\nslip = " + (
        f"{s:6.3f}" if s is not None else "   —  "
    )


def _add_label(ax: Axes) -> Text:
    return ax.text(
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


def _wheel_patch(ax: Axes, visible: bool, fill: bool = True) -> Polygon:
    from matplotlib.patches import Polygon

    patch = Polygon(
        np.zeros((3, 2)),
        closed=True,
        facecolor="#b8c4d0" if fill else "none",
        edgecolor="k",
        linewidth=0.8 if fill else 1.2,
        zorder=5,
        visible=visible,
    )
    ax.add_patch(patch)
    return patch


def _mesh_patch(ax: Any, fill: bool) -> Any:
    """The collection a mesh wheel's projected triangles are drawn with."""
    from matplotlib.collections import PolyCollection

    if fill:  # the cut: the triangles crossing the slab, edged so the rim's side shows as a ring
        coll = PolyCollection([], facecolors="#b8c2d0", edgecolors="#404858", linewidths=0.8, zorder=5)
    else:  # the side view: a shadow (unedged, not antialiased: no seams between triangles)
        coll = PolyCollection([], facecolors="#8090a8", alpha=0.3, linewidths=0.0, antialiased=False, zorder=5)
    ax.add_collection(coll)
    return coll


def _outline(wheel: Wheel, ws: NDArray[np.float64]) -> NDArray[np.float64]:
    w = wheel
    return wheel_outline(ws[0], ws[1], ws[4], w.radius, w.n_lugs, w.lug_tip_radius, w.lug_thickness)


def _film_size(xa: float, xb: float, ya: float, yb: float, panels: int = 1) -> tuple[int, int, float]:
    """(width, height of one panel in pixels (the film's height a multiple of 16), the
    panel's top in metres): equal scale in x and y."""
    W = WIDTH_PX
    H = max(16 // panels, int(round(W * (yb - ya) / (xb - xa) * panels / 16.0)) * 16 // panels)
    return W, H, ya + (xb - xa) * H / W


class Scene2D:
    """The 2D film's picture: every disc in its initial layer's colour, the wheel on top."""

    def __init__(self, traj: Trajectory, sc: Scenario | None, run_dir: Path) -> None:
        from ..model.fields import layer_index
        from .drawing import layer_count, pyplot
        from matplotlib.colors import to_rgba_array

        first = traj[0]
        x0, y0, r0 = first["pos"][:, 0], first["pos"][:, 1], first["r"]
        init = run_file(run_dir, "initial.npz")
        surface = (
            read_initial(init, len(first["id"]), sc)[4] if init is not None else float(np.max(y0 + r0, initial=0.0))
        )
        layer = layer_index(y0, surface, layer_count(surface, r0))
        self.palette = to_rgba_array(list(LAYER_COLOURS) + ["#4a7fbf"])  # the layers, then "unknown disc"
        self.colour_of = (layer % 2).astype(np.int8)
        self.ids0 = first["id"]
        # the view: the bin (or the discs) from the floor to above the wheel's highest point
        if sc is not None:
            xa, xb = 0.0, sc.bin.length
        else:
            xa, xb = float(np.min(x0 - r0, initial=0.0)), float(np.max(x0 + r0, initial=1.0))
        ya = 0.0
        self.wheel = sc.wheel if sc is not None and sc.wheel.enabled else None  # None: no wheel drawn
        yb = _view_top(traj, self.wheel, max(surface, float(np.max(y0 + r0, initial=0.0))))
        yb += 0.03 * (yb - ya)
        W, H, yb = _film_size(xa, xb, ya, yb)
        self.size = (W, H)
        plt = pyplot()
        dpi = 100
        self.fig = fig = plt.figure(figsize=(W / dpi, H / dpi), dpi=dpi)
        self.ax = ax = fig.add_axes((0, 0, 1, 1))
        ax.set_xlim(xa, xb)
        ax.set_ylim(ya, yb)
        ax.set_axis_off()
        ax.set_facecolor("white")
        self.coll: EllipseCollection | None = None
        self.wpatch = _wheel_patch(ax, self.wheel is not None)
        self.label = _add_label(ax)

    def draw(self, fr: Frame) -> None:
        from matplotlib.collections import EllipseCollection

        ids, pos, r = fr["id"], fr["pos"], fr["r"]
        ids0, coll = self.ids0, self.coll
        if coll is None or len(ids) != len(np.asarray(coll.get_offsets())):
            if coll is not None:
                coll.remove()
            at = np.clip(np.searchsorted(ids0, ids), 0, max(len(ids0) - 1, 0))
            known = (ids0[at] == ids) if len(ids0) else np.zeros(len(ids), bool)
            fc = self.palette[np.where(known, self.colour_of[at] if len(ids0) else 2, 2)]
            d = 2.0 * r
            self.coll = EllipseCollection(
                d,
                d,
                np.zeros_like(d),
                units="xy",
                offsets=pos,
                offset_transform=self.ax.transData,
                facecolors=fc,
                edgecolors="#3a2a1a",
                linewidths=0.15,
                zorder=1,
            )
            self.ax.add_collection(self.coll)
        else:
            coll.set_offsets(pos)
        if self.wheel is not None:
            self.wpatch.set_xy(_outline(self.wheel, fr["wheel_state"]))
        self.label.set_text(_frame_label(fr, self.wheel))


class Scene3D:
    """The 3D film's picture, two panels of the x-y plane seen from the +z side: on top the
    side view of the whole bed, below the cut at the wheel's mid-plane (the spheres with
    |z - z_wheel| < CUT_HALF_WIDTH r_max). Spheres are splatted (``film3d.SphereSplatter``)
    in the colour of their speed (0 .. the lug tips' speed |omega| R_tip, or the last frame's
    99th percentile without a wheel) or height (floor .. the bed's initial top); the wheel's
    outline (rim and lugs, at the frame's pose) is drawn over both, filled in the cut."""

    CUT_HALF_WIDTH = 1.5

    def __init__(self, traj: Trajectory, sc: Scenario | None, colour: str) -> None:
        from .drawing import pyplot

        first = traj[0]
        pos0, r0 = first["pos"], first["r"]
        self.wheel = sc.wheel if sc is not None and sc.wheel.enabled else None
        if sc is not None:
            xa, xb = 0.0, float(sc.bin.length)
            r_max = float(sc.soil.r_max)
        else:
            xa = float(np.min(pos0[:, 0] - r0, initial=0.0))
            xb = float(np.max(pos0[:, 0] + r0, initial=1.0))
            r_max = float(np.max(r0, initial=0.0))
        self.geometry = WheelGeometry.of_scenario(sc) if self.wheel is not None and sc is not None else None
        if self.geometry is not None:
            self.z_cut = self.geometry.z_centre
        else:
            self.z_cut = float(np.median(pos0[:, 2])) if len(r0) else 0.0
        self.half = self.CUT_HALF_WIDTH * r_max
        ya = 0.0
        top = float(np.max(pos0[:, 1] + r0, initial=0.0))
        yb = _view_top(traj, self.wheel, top)
        yb += 0.03 * (yb - ya)
        W, H, yb = _film_size(xa, xb, ya, yb, panels=2)
        self.size = (W, 2 * H)
        self.colour = colour
        if colour == "height":
            self.range = (0.0, max(top, 1e-12))
        elif self.wheel is not None and abs(self.wheel.omega) > 0.0:
            self.range = (0.0, abs(self.wheel.omega) * self.wheel.lug_tip_radius)
        else:
            last = traj[len(traj) - 1]["vel"]
            self.range = (
                0.0,
                max(float(np.percentile(np.linalg.norm(last, axis=1), 99.0)) if len(last) else 0.0, 1e-6),
            )
        self.splat = SphereSplatter(W, H, xa, xb, ya, yb)
        plt = pyplot()
        dpi = 100
        self.fig = fig = plt.figure(figsize=(W / dpi, 2 * H / dpi), dpi=dpi)
        blank = np.full((H, W, 3), 255, np.uint8)
        self.images = []
        self.patches = []
        captions = ("side view", f"cut |z - {self.z_cut:.3f} m| < {self.half * 1e3:.1f} mm")
        for k, caption in enumerate(captions):
            ax = fig.add_axes((0.0, 0.5 * (1 - k), 1.0, 0.5))
            ax.set_xlim(xa, xb)
            ax.set_ylim(ya, yb)
            ax.set_axis_off()
            self.images.append(
                ax.imshow(blank, extent=(xa, xb, ya, yb), origin="upper", interpolation="nearest", zorder=1)
            )
            if self.geometry is not None and self.geometry.mesh is not None:
                # a mesh wheel: its triangles projected on x-y, a shadow over the side view,
                # those near the mid-plane filled in the cut
                self.patches.append(_mesh_patch(ax, fill=k == 1))
            else:
                self.patches.append(_wheel_patch(ax, self.wheel is not None, fill=k == 1))
            ax.text(0.99, 0.98, caption, transform=ax.transAxes, va="top", ha="right", fontsize=12, zorder=10)
            if k == 1:
                ax.axhline(yb, color="0.3", linewidth=1.5, zorder=10)
                lo, hi = self.range
                unit = "m/s" if colour == "speed" else "m"
                ax.text(
                    0.99,
                    0.90,
                    f"colour: {colour} {lo:g} .. {hi:.3g} {unit}",
                    transform=ax.transAxes,
                    va="top",
                    ha="right",
                    fontsize=11,
                    zorder=10,
                )
            if k == 0:
                self.label = _add_label(ax)

    def pictures(self, fr: Frame) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        """The two panels' pictures of the spheres of a frame (side view, cut)."""
        pos, r = fr["pos"], fr["r"]
        lo, hi = self.range
        value = np.linalg.norm(fr["vel"], axis=1) if self.colour == "speed" else pos[:, 1]
        # speed: sand-coloured at rest, red where the wheel drives the soil; height: layers
        rgb = colour_map(value, lo, hi, "YlOrRd", 0.15) if self.colour == "speed" else colour_map(value, lo, hi)
        cut = np.abs(pos[:, 2] - self.z_cut) < self.half
        return self.splat.render(pos, r, rgb), self.splat.render(pos[cut], r[cut], rgb[cut])

    def draw(self, fr: Frame) -> None:
        for image, picture in zip(self.images, self.pictures(fr)):
            image.set_data(picture)
        if self.geometry is not None and self.geometry.mesh is not None:
            ws = fr["wheel_state"]
            tri = mesh_at_pose(self.geometry, ws[0], ws[1], ws[4])
            z = tri[..., 2]
            near = (z.min(axis=1) < self.z_cut + self.half) & (z.max(axis=1) > self.z_cut - self.half)
            self.patches[0].set_verts(tri[..., :2])
            self.patches[1].set_verts(tri[near][..., :2])
        elif self.wheel is not None:
            outline = _outline(self.wheel, fr["wheel_state"])
            for patch in self.patches:
                patch.set_xy(outline)
        self.label.set_text(_frame_label(fr, self.wheel))


def _film(traj: Trajectory, scene: Scene2D | Scene3D, out: Path, fps: int, progress: bool) -> int:
    """Draw every frame of ``traj`` with ``scene`` and encode the film to ``out`` (written
    under a temporary name); returns the number of frames."""
    from .outfile import ExportError

    import imageio.v2 as iio

    ext = out.suffix.lower()
    W, H = scene.size
    fig = scene.fig
    bar = None
    if progress:
        import sys
        from tqdm import tqdm

        bar = tqdm(total=len(traj), desc=f"animate {out.name}", unit="frame", file=sys.stderr, dynamic_ncols=True)

    def write(tmp: Path) -> int:
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
                scene.draw(fr)
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
        return _write_replacing_suffixed(out, write)
    except OSError as e:
        raise ExportError(f"--out {out}: cannot write ({e.strerror or e})") from None
    finally:
        if bar is not None:
            bar.close()
        from .drawing import pyplot

        pyplot().close(fig)


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
