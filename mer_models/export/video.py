"""A moving picture of a retargeting: the scaled reference and the retarget side by side (GIF or MP4).

Two 3D panels drawn with matplotlib (Agg, no window): on the left the reference scaled to the
target -- the goals the energy tracks (:func:`mer_data.motion.samples.reference_goals`), drawn as the
reference skeleton's bones on its scaled node positions with the tracked key points as red dots --
and on the right the retargeted robot (bones = parent links of its skeleton from FK, key points
in orange). Both panels share one fixed camera (elevation 15 deg, a three-quarter view of the
initial heading), equal axes and bounds over the whole motion, so sizes, heights and distances
compare across panels and frames. A label shows the frame and the time.

Formats, by the file's ending:

* ``.gif``: written with Pillow (a matplotlib dependency, so part of the base install); one
  256-colour palette from the first frame; frame delays in centiseconds (GIF's unit) rounded
  cumulatively so the clip plays at its true speed. Pillow holds every frame until it writes
  (~0.3 MB per 800x400 frame: a 60 s clip at 30 Hz needs ~0.6 GB; lower ``fps`` or use MP4).
* ``.mp4``: H.264 through the ``ffmpeg`` program (``PATH``, or the binary of the optional
  ``imageio-ffmpeg`` package), frames streamed to it; without one, :func:`check_video_path`
  refuses before any work.

The panes, grids and titles are drawn once; each frame redraws only the figures and the label
(blitting): ~15 ms per 800x400 frame on the 2-core development machine (docs/model.md). ``fps``
below the motion's rate keeps the frame nearest to each output time. Files are written to a
temporary sibling and renamed: nothing half-written is ever visible under the final name.
"""

from __future__ import annotations

import io
import logging
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from mer_data.base.atomic import atomic_write, owner_tag
from mer_data.base.errors import MerError
from mer_data.robots.registry import Robot
from mer_data.skeleton import Skeleton

from .geometry import RobotMeshes
from .video_render import VIDEO_MAX_FACES, VideoRenderer, swatches
from .writers import TargetMotion, check_motion_finite

log = logging.getLogger(__name__)

__all__ = [
    "parse_time_range",
    "DEFAULT_VIDEO_SECONDS",
    "VIDEO_FORMATS",
    "GIF_MAX_FPS",
    "check_video_path",
    "find_ffmpeg",
    "video_frame_indices",
    "write_video",
]

#: File endings and what writes them.
VIDEO_FORMATS = {".gif": "Pillow", ".mp4": "ffmpeg"}
#: Browsers and viewers slow GIF frame delays under 20 ms down to 100 ms: 50 frames/s at most.
GIF_MAX_FPS = 50.0
_INSTALL_FFMPEG = "install ffmpeg (apt install ffmpeg, conda install ffmpeg, brew install ffmpeg, or pip install imageio-ffmpeg), or write a .gif instead"


def find_ffmpeg() -> str | None:
    """The ffmpeg program: ``ffmpeg`` on ``PATH``, else the one of ``imageio-ffmpeg`` if installed."""
    exe = shutil.which("ffmpeg")
    if exe is not None:
        return exe
    try:
        import imageio_ffmpeg  # optional: a pip-installable static ffmpeg
    except ImportError:
        return None
    try:
        return imageio_ffmpeg.get_ffmpeg_exe()
    except Exception:  # noqa: BLE001 - a broken install counts as none
        return None


def check_video_path(path: str | Path, fps: float | None = None) -> str:
    """The format (``gif`` or ``mp4``) of ``path``, or MerError: unknown ending, no ffmpeg for MP4, GIF too fast.

    Cheap: call it before retargeting so a bad option fails at once.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in VIDEO_FORMATS:
        raise MerError(
            f"unknown video format {suffix or '(no ending)'!r}",
            path=path,
            fix=f"name the video file .gif (works with the base install) or .mp4 (needs ffmpeg), e.g. {Path(path).stem or 'out'}.gif",
        )
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise MerError(f"video frame rate {fps!r} is not a positive number", path=path, fix="pass e.g. --video-fps 15")
    if suffix == ".gif" and fps is not None and fps > GIF_MAX_FPS:
        raise MerError(
            f"{fps:g} frames/s is too fast for a GIF: players slow frame delays under 20 ms down to 100 ms",
            path=path,
            fix=f"pass --video-fps {GIF_MAX_FPS:g} or less, or write an .mp4",
        )
    if suffix == ".mp4" and find_ffmpeg() is None:
        raise MerError("writing an MP4 needs the ffmpeg program, which was not found", path=path, fix=_INSTALL_FFMPEG)
    return suffix[1:]


def video_frame_indices(num_frames: int, fps: float, video_fps: float | None) -> np.ndarray:
    """Frames shown (nearest to every ``1 / video_fps`` s; all at ``video_fps`` >= ``fps`` or None)."""
    if video_fps is None or video_fps >= fps:
        return np.arange(num_frames)
    times = np.arange(0.0, (num_frames - 1) / fps + 1e-9, 1.0 / video_fps)
    return np.unique(np.clip(np.round(times * fps).astype(int), 0, num_frames - 1))


#: Without a time range, a video shows at most this many seconds from the start (a message says so).
DEFAULT_VIDEO_SECONDS = 10.0
#: A GIF's frame rate without ``fps`` [Hz]: 10 s at 800x400 stay under ~5 MB.
DEFAULT_GIF_FPS = 15.0


def parse_time_range(text: str) -> tuple[float, float | None]:
    """``START:END`` seconds (either may be empty: ``:5``, ``12:``) → (start, end or None)."""
    a, sep, b = str(text).partition(":")
    try:
        start = float(a) if a.strip() else 0.0
        end = float(b) if b.strip() else None
    except ValueError:
        start, end = -1.0, None
    if not sep or start < 0 or not np.isfinite(start) or (end is not None and (not np.isfinite(end) or end <= start)):
        raise MerError(f"video range {text!r} is not START:END in seconds with 0 <= START < END",
                       fix="e.g. --video-range 0:10, --video-range 30: (to the end)")  # fmt: skip
    return start, end


def _gif_durations(count: int, fps: float) -> list[int]:
    """Per-frame delays [ms], multiples of 10 (GIF stores centiseconds) whose sum keeps the true clock."""
    cs = np.round(np.arange(count + 1) * 100.0 / fps).astype(int)
    return [int(d) * 10 for d in np.maximum(np.diff(cs), 1)]


def _write_gif(path: Path, frames, count: int, fps: float) -> Path:
    from PIL import Image

    images, palette = [], None
    for rgb in frames:
        im = Image.fromarray(rgb)
        if palette is None:  # one palette: the first frame and the swatches of every colour drawn
            sw, per_row = swatches(), max(1, rgb.shape[1] // 8)  # 8 x 8 px each, rows as wide as the frame
            rows = -(-len(sw) // per_row)
            cells = np.full((rows * per_row, 3), 255, np.uint8)
            cells[: len(sw)] = sw
            block = np.repeat(np.repeat(cells.reshape(rows, per_row, 3), 8, axis=0), 8, axis=1)
            block = np.pad(block, ((0, 0), (0, rgb.shape[1] - block.shape[1]), (0, 0)), constant_values=255)
            both = Image.fromarray(np.concatenate([rgb, block]))
            palette = both.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
        images.append(im.quantize(palette=palette, dither=Image.Dither.NONE))
    if len(images) != count:
        raise RuntimeError(f"rendered {len(images)} frames, expected {count}")
    buf = io.BytesIO()
    # optimize=False: Pillow would otherwise drop palette entries per frame (slow, and nothing to gain here)
    images[0].save(buf, format="GIF", save_all=True, append_images=images[1:], duration=_gif_durations(count, fps),
                   loop=0, optimize=False, disposal=1)  # fmt: skip
    return atomic_write(path, buf.getvalue())


def _write_mp4(path: Path, frames, size: tuple[int, int], fps: float) -> Path:
    exe = find_ffmpeg()
    if exe is None:
        raise MerError("writing an MP4 needs the ffmpeg program, which was not found", path=path, fix=_INSTALL_FFMPEG)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".tmp-{path.name}~{owner_tag()}~", dir=path.parent)
    os.close(fd)
    cmd = [exe, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{size[0]}x{size[1]}", "-r", f"{fps:.6g}",
           "-i", "-", "-an", "-c:v", "libx264", "-pix_fmt", "yuv420p", "-movflags", "+faststart", "-f", "mp4", tmp]  # fmt: skip
    proc = None
    with tempfile.TemporaryFile() as log_file:  # ffmpeg's messages (a file, not a pipe: a pipe that fills up would block it)
        try:
            proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=log_file)
            try:
                for rgb in frames:
                    proc.stdin.write(rgb.tobytes())
            except BrokenPipeError:
                pass  # ffmpeg stopped early: its exit status and message follow
            finally:
                try:
                    proc.stdin.close()  # end of input (or, after an error, ffmpeg is killed below)
                except BrokenPipeError:
                    pass
            proc.wait()
            if proc.returncode != 0:
                log_file.seek(0)
                tail = log_file.read().decode("utf-8", "replace").strip().splitlines()[-3:]
                raise MerError(f"ffmpeg failed (exit {proc.returncode}): {' | '.join(tail) or 'no message'}", path=path,
                               fix="check that this ffmpeg has the libx264 encoder (`ffmpeg -encoders`), or write a .gif")  # fmt: skip
            with open(tmp, "rb") as fh:
                os.fsync(fh.fileno())
            os.chmod(tmp, 0o666 & ~_umask())
            os.replace(tmp, path)
        except BaseException:
            if proc is not None and proc.poll() is None:
                proc.kill()  # a frame failed to render: stop ffmpeg, keep nothing
                proc.wait()
            Path(tmp).unlink(missing_ok=True)
            raise
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_video(
    path: str | Path,
    motion: TargetMotion,
    reference_points: np.ndarray,
    *,
    reference_nodes: np.ndarray | None = None,
    reference_skeleton: Skeleton | None = None,
    fps: float | None = None,
    size: tuple[int, int] = (800, 400),
    title: str | None = None,
    time_range: tuple[float, float | None] | None = None,
    robot: Robot | None = None,
    mesh_dir: str | Path | None = None,
    meshes: RobotMeshes | None = None,
) -> Path:
    """Write the side-by-side video (GIF or MP4, by the ending of ``path``; module docstring).

    Args:
        motion: the retargeted motion (world frame), F frames at ``motion.fps``.
        reference_points: (F, K, 3) the scaled reference key points the energy tracks [m], world frame.
        reference_nodes: (F, Jr, 3) every node of the scaled reference [m] (its bones are drawn when
            ``reference_skeleton`` is given too; without them the left panel shows the goals only).
        reference_skeleton: the reference (source) skeleton, for the parent links of ``reference_nodes``.
        fps: frame rate of the video [Hz]; default the motion's (MP4) or :data:`DEFAULT_GIF_FPS`
            (GIF). Lower keeps every k-th frame.
        size: (width, height) [px], both even (MP4's colour format needs it).
        title: a line above the panels.
        time_range: (start, end) [s] of the motion to show (end None: to the end); None: the first
            :data:`DEFAULT_VIDEO_SECONDS` (a message says when that cuts the clip).
        robot: the motion's registered robot (default: the robot the skeleton is named after, when
            the skeleton is its own; a scaled or augmented skeleton is drawn as bones).
        mesh_dir: a folder to look for the robot's mesh files in besides the registered
            description's (:func:`~mer_models.export.geometry.robot_meshes`).
        meshes: what draws the robot, if made already (default: :func:`~mer_models.export.geometry.robot_meshes`
            with :data:`VIDEO_MAX_FACES`).

    Returns:
        ``path``. Raises MerError for an unknown ending, a missing ffmpeg (MP4), mismatched shapes
        or a non-finite motion; nothing is written then.
    """
    path = Path(path)
    kind = check_video_path(path, fps)
    if fps is None and kind == "gif":
        fps = DEFAULT_GIF_FPS
    check_motion_finite(motion, path)
    F = motion.num_frames
    goals = np.asarray(reference_points, np.float64)
    if goals.ndim != 3 or goals.shape[0] != F or goals.shape[2] != 3:
        raise MerError(f"reference_points have shape {goals.shape}, expected ({F}, K, 3)", path=path)
    nodes = None if reference_nodes is None else np.asarray(reference_nodes, np.float64)
    if nodes is not None:
        want = (F, reference_skeleton.num_nodes if reference_skeleton is not None else nodes.shape[1], 3)
        if nodes.shape != want:
            raise MerError(f"reference_nodes have shape {nodes.shape}, expected {want}", path=path)
    if not (np.isfinite(goals).all() and (nodes is None or np.isfinite(nodes).all())):
        raise MerError("the reference has non-finite positions", path=path, fix="retarget from a finite source motion")
    w, h = (int(v) for v in size)
    if w < 64 or h < 64 or w % 2 or h % 2:
        raise MerError(f"video size {w}x{h}: width and height must be even and at least 64 px", path=path)
    out_fps = float(fps) if fps is not None and fps < motion.fps else float(motion.fps)
    idx = video_frame_indices(F, motion.fps, fps)
    t = idx / motion.fps
    if time_range is None:
        start, end = 0.0, DEFAULT_VIDEO_SECONDS
        if t[-1] > end + 1e-9:
            log.warning("%s: showing the first %g s of %.1f s (--video-range START:END for another part)", path, end, t[-1])
    else:
        start, end = time_range
    idx = idx[(t >= start - 1e-9) & (t <= (np.inf if end is None else end) + 1e-9)]
    if not len(idx):
        raise MerError(f"the video range {start:g}:{'' if end is None else f'{end:g}'} s holds no frame of the "
                       f"{(F - 1) / motion.fps:.1f} s motion", path=path, fix="pass a range inside the motion")  # fmt: skip
    robot_pos, robot_rot = motion.forward_kinematics()
    t0 = time.perf_counter()
    body_poses = None
    if meshes is None:
        from mer_data.shards.foxglove import registered_robot

        robot = robot if robot is not None else registered_robot(motion.skeleton)
        if robot is not None and robot.skeleton.fingerprint == motion.skeleton.fingerprint:
            from .geometry import robot_meshes

            meshes = robot_meshes(robot, mesh_dir=mesh_dir, max_faces=VIDEO_MAX_FACES)
    if meshes is not None:
        from mer_data.robots.articulation import articulation
        from mer_data.robots.registry import load_robot

        art = articulation(robot if robot is not None else load_robot(meshes.robot))
        if art.body_names != meshes.body_names or art.skeleton_fingerprint != motion.skeleton.fingerprint:
            raise MerError(f"the meshes of {meshes.robot!r} do not belong to the motion's skeleton {motion.skeleton.name!r}",
                           path=path, fix="draw the motion with its own robot's meshes")  # fmt: skip
        body_poses = art.body_poses(robot_pos, robot_rot)
    r = VideoRenderer(motion, robot_pos, goals, nodes, reference_skeleton if nodes is not None else None, (w, h), title, shown=idx,
                  meshes=meshes, body_poses=body_poses)  # fmt: skip
    try:
        frames = (r.frame(int(f)) for f in idx)
        if kind == "gif":
            out = _write_gif(path, frames, len(idx), out_fps)
        else:
            out = _write_mp4(path, frames, (r.width, r.height), out_fps)
    finally:
        r.fig.clear()
    dt = time.perf_counter() - t0
    drawn = "bones" if meshes is None else f"{meshes.kind} ({meshes.num_faces} faces)"
    log.info("%s: %d frames at %g Hz in %.1f s (%.0f ms per frame), robot drawn as %s", out, len(idx), out_fps, dt,
             1e3 * dt / len(idx), drawn)  # fmt: skip
    return out
