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


def _bones(pos: np.ndarray, parents) -> np.ndarray:
    """(J, 3) node positions → (J-1, 2, 3) parent → child segments."""
    child = np.arange(1, len(parents))
    return np.stack([pos[np.asarray(parents)[child]], pos[child]], axis=1)


def _bounds(*clouds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Low and high corners (3,) of every point, padded, with the floor (z = 0) included."""
    pts = np.concatenate([c.reshape(-1, 3) for c in clouds])
    lo, hi = pts.min(0), pts.max(0)
    lo[2] = min(lo[2], 0.0)
    pad = 0.05 * max(float((hi - lo).max()), 0.5)
    return lo - pad, hi + pad


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


def _centred(x: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(F, N, 3) positions moved so that each frame's ``centre`` (F, 2) is at x = y = 0."""
    out = np.array(x, np.float64, copy=True)
    out[..., :2] -= centre[:, None, :]
    return out


#: Colours of what is drawn (RGB in [0, 1]): the robot's visual meshes, its collision shapes, the
#: scaled reference, a foot in contact, the floor. A test tells meshes from shapes by their colour.
MESH_RGB = (0.42, 0.60, 0.86)
COLLISION_RGB = (0.86, 0.60, 0.32)
REFERENCE_RGB = (0.84, 0.15, 0.16)
CONTACT_RGB = (0.20, 0.66, 0.20)
FLOOR_RGB = (0.93, 0.93, 0.93)
#: The face budget of the robot in a video: enough for its shape at 400 px, fast to draw.
VIDEO_MAX_FACES = 6000
_GRID = 0.5  # floor grid spacing [m]
_DISC = 0.08  # radius of a contact mark [m]


def _view_vector(elev: float, azim: float) -> np.ndarray:
    """(3,) unit vector from the scene towards matplotlib's camera at ``elev``, ``azim`` [deg]."""
    e, a = np.radians(elev), np.radians(azim)
    return np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def _flat_polygons(**kw):
    """A 2D polygon collection in a 3D panel, its vertices already projected (:meth:`_MeshLayer.update`)."""
    from matplotlib.collections import PolyCollection

    class FlatPolygons(PolyCollection):
        def do_3d_projection(self) -> float:  # what the 3D panel asks every collection: nothing to project
            return 0.0

    return FlatPolygons([], closed=True, linewidths=0.0, **kw)


class _MeshLayer:
    """The robot's triangles in one 3D panel: moved by the body poses, projected with the panel's
    fixed camera, back faces dropped, shaded by a light from behind the camera, drawn far to near."""

    def __init__(self, meshes: RobotMeshes) -> None:
        body, local, faces, rgb, n = [], [], [], [], 0
        for bm in meshes.bodies:
            body.append(np.full(len(bm.vertices), bm.body))
            local.append(bm.vertices)
            faces.append(bm.faces + n)
            rgb.append(np.tile(MESH_RGB if bm.source == "mesh" else COLLISION_RGB, (len(bm.faces), 1)))
            n += len(bm.vertices)
        self.body, self.local = np.concatenate(body), np.concatenate(local)
        self.faces, self.rgb = np.concatenate(faces), np.concatenate(rgb)
        self.ax = self.coll = None

    def world(self, pos: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """(V, 3) vertices in the world [m] at body positions (B, 3) and rotations (B, 3, 3)."""
        return np.einsum("nij,nj->ni", rot[self.body], self.local) + pos[self.body]

    def attach(self, ax, toward_camera: np.ndarray) -> None:
        """Draw into panel ``ax``, lit from ``toward_camera`` (3,) (and above)."""
        light = toward_camera + np.array([0.0, 0.0, 0.8]) + 0.4 * np.cross([0.0, 0.0, 1.0], toward_camera)
        self.light = light / np.linalg.norm(light)
        self.ax = ax
        self.coll = _flat_polygons(antialiased=False, zorder=3)
        ax.add_collection(self.coll, autolim=False)

    def update(self, pos: np.ndarray, rot: np.ndarray) -> None:
        """Body positions (B, 3) [m] (already centred) and rotations (B, 3, 3) of one frame."""
        from mpl_toolkits.mplot3d import proj3d

        w = self.world(pos, rot)
        x, y, z = proj3d.proj_transform(w[:, 0], w[:, 1], w[:, 2], self.ax.M)
        f = self.faces
        xy = np.stack([x, y], axis=-1)[f]  # (T, 3, 2)
        d1, d2 = xy[:, 1] - xy[:, 0], xy[:, 2] - xy[:, 0]
        front = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0] > 0  # counter-clockwise on screen: faces the camera
        tri = w[f[front]]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        shade = 0.45 + 0.55 * np.clip(normal @ self.light, 0.0, 1.0)
        order = np.argsort(-z[f[front]].mean(1), kind="stable")  # far (large z) first
        self.coll.set_verts(xy[front][order])
        self.coll.set_facecolor(np.clip(self.rgb[front][order] * shade[order, None], 0.0, 1.0))


class _Renderer:
    """One reused figure: two 3D panels whose artists are moved to each frame. The camera follows
    the robot: every frame is drawn about its base's x, y (the floor grid and path scroll under it).
    The right panel draws the robot's meshes (or collision shapes) where ``meshes`` is given, else
    its skeleton's bones; feet in contact are marked on the floor in both panels."""

    def __init__(self, motion: TargetMotion, robot_pos: np.ndarray, goals: np.ndarray, ref_nodes: np.ndarray | None,
                 ref_skel: Skeleton | None, size: tuple[int, int], title: str | None, shown: np.ndarray | None = None,
                 meshes: RobotMeshes | None = None, body_poses: tuple[np.ndarray, np.ndarray] | None = None) -> None:  # fmt: skip
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

        from mer_data.motion.contacts import foot_contacts, sole_points

        self.centre = np.asarray(robot_pos[:, 0, :2], np.float64)
        self.path = np.array(robot_pos[:, 0], np.float64)
        if shown is not None and len(shown):  # the base's path over the part shown only
            self.path[: int(np.min(shown))] = np.nan
            self.path[int(np.max(shown)) + 1 :] = np.nan
        skel = motion.skeleton
        self.feet = [self._feet(robot_pos, skel, foot_contacts(robot_pos, skel, motion.fps), sole_points(skel))]
        if ref_nodes is not None and ref_skel is not None:
            self.feet.insert(
                0, self._feet(ref_nodes, ref_skel, foot_contacts(ref_nodes, ref_skel, motion.fps), sole_points(ref_skel))
            )
        else:
            self.feet.insert(0, None)
        robot_pos, goals = _centred(robot_pos, self.centre), _centred(goals, self.centre)
        ref_nodes = None if ref_nodes is None else _centred(ref_nodes, self.centre)
        self.motion, self.robot_pos, self.goals, self.ref_nodes, self.ref_skel = motion, robot_pos, goals, ref_nodes, ref_skel
        self.body_pos = None if body_poses is None else _centred(body_poses[0], self.centre)
        self.body_rot = None if body_poses is None else body_poses[1]
        self.key = np.array([j for j in skel.keypoints.values() if j >= 0], dtype=int)
        dpi = 100
        self.fig = Figure(figsize=(size[0] / dpi, size[1] / dpi), dpi=dpi)
        self.canvas = FigureCanvasAgg(self.fig)
        sel = slice(None) if shown is None else shown
        clouds = [robot_pos[sel], goals[sel]] + ([ref_nodes[sel]] if ref_nodes is not None else [])
        self.mesh = _MeshLayer(meshes) if meshes is not None and meshes.bodies and self.body_pos is not None else None
        if self.mesh is not None:  # the meshes' extent (a head above its joint) on some of the frames shown
            some = np.arange(len(self.body_pos))[sel][::10]
            clouds += [np.stack([self.mesh.world(self.body_pos[f], self.body_rot[f]) for f in some])]
        lo, hi = _bounds(*clouds)
        self.lo, self.hi = lo, hi
        r0 = np.asarray(motion.base_rot[0])
        azim = float(np.degrees(np.arctan2(r0[1, 0], r0[0, 0]))) - 60.0  # three-quarter view of the initial heading
        self.axes = []
        for i, name in enumerate((f"reference scaled to {skel.name} (goals)", f"retarget: {skel.name}")):
            ax = self.fig.add_axes((0.5 * i, 0.06, 0.5, 0.88), projection="3d")
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(lo[1], hi[1])
            ax.set_zlim(lo[2], hi[2])
            ax.set_box_aspect(tuple(hi - lo), zoom=1.25)  # equal axes: 1 m is as long along x, y and z
            ax.view_init(elev=15.0, azim=azim)
            ax.set_axis_off()  # the floor grid gives the scale (0.5 m squares)
            ax.set_title(name, fontsize=9, y=0.97)
            floor = [[(lo[0], lo[1], 0.0), (hi[0], lo[1], 0.0), (hi[0], hi[1], 0.0), (lo[0], hi[1], 0.0)]]
            ax.add_collection3d(Poly3DCollection(floor, facecolors=[FLOOR_RGB], edgecolors="none"), autolim=False)
            self.axes.append(ax)
        ref_ax, rob_ax = self.axes
        self.grids = [Line3DCollection([], colors="0.72", linewidths=0.6) for _ in self.axes]
        self.discs = [_flat_polygons(facecolors=[CONTACT_RGB], zorder=2) for _ in self.axes]
        for ax, grid, disc in zip(self.axes, self.grids, self.discs):
            ax.add_collection3d(grid, autolim=False)
            ax.add_collection(disc, autolim=False)
        self.ref_bones = None
        if ref_skel is not None:
            self.ref_bones = Line3DCollection(_bones(ref_nodes[0], ref_skel.parents), colors=[REFERENCE_RGB], linewidths=1.5)
            ref_ax.add_collection3d(self.ref_bones, autolim=False)
        (self.ref_dots,) = ref_ax.plot([], [], [], "o", color=REFERENCE_RGB, ms=3)
        self.rob_bones = self.rob_dots = None
        if self.mesh is None or meshes.kind != "mesh":  # bones: of a skeleton without a robot, or joining collision shapes
            colour, width = ("0.3", 1.5) if self.mesh is None else ("0.55", 2.5)  # not the meshes' blue
            self.rob_bones = Line3DCollection(_bones(robot_pos[0], skel.parents), colors=colour, linewidths=width)
            rob_ax.add_collection3d(self.rob_bones, autolim=False)
        if self.mesh is None:
            (self.rob_dots,) = rob_ax.plot([], [], [], "o", color="tab:orange", ms=3)
        else:
            self.mesh.attach(rob_ax, _view_vector(15.0, azim))
        self.paths = [ax.plot([], [], [], color="0.45", lw=1.0)[0] for ax in self.axes]  # the base's path on the floor
        self.label = self.fig.text(0.5, 0.015, "", ha="center", fontsize=9, family="monospace")
        self.fig.suptitle(title or "", fontsize=9, y=0.995)
        self.width, self.height = self.canvas.get_width_height()
        # blitting: the floor and titles never move; draw them once, keep the pixels
        moving = [*self.grids, *self.paths, *self.discs, self.ref_bones, self.ref_dots, self.rob_bones, self.rob_dots,
                  self.mesh.coll if self.mesh is not None else None, self.label]  # fmt: skip
        self.moving = [a for a in moving if a is not None]
        for a in self.moving:
            a.set_animated(True)
        self.canvas.draw()  # also fixes each panel's projection (ax.M), which the moving artists use
        self.background = self.canvas.copy_from_bbox(self.fig.bbox)

    @staticmethod
    def _feet(pos: np.ndarray, skel: Skeleton, contact: np.ndarray, soles: dict[str, list[int]]) -> np.ndarray:
        """(F, 2, 3) the lowest sole point of each foot, NaN where the foot is not in contact."""
        out = np.full((pos.shape[0], 2, 3), np.nan)
        for i, nodes in enumerate(soles.values()):
            if nodes:
                p = pos[:, nodes]
                low = p[np.arange(len(p)), p[..., 2].argmin(1)]
                out[contact[:, i], i] = low[contact[:, i]]
        return out

    def _floor(self, i: int, f: int) -> None:
        """Panel ``i``'s grid lines (world-fixed, moved with the camera) and contact marks at frame ``f``."""
        from mpl_toolkits.mplot3d import proj3d

        c, lo, hi = self.centre[f], self.lo, self.hi
        segs = []
        for axis in (0, 1):
            first = np.ceil((lo[axis] + c[axis]) / _GRID) * _GRID
            for v in np.arange(first, hi[axis] + c[axis] + 1e-9, _GRID) - c[axis]:
                a, b = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
                a[axis] = b[axis] = v
                a[1 - axis], b[1 - axis] = lo[1 - axis], hi[1 - axis]
                segs.append([a, b])
        self.grids[i].set_segments(segs)
        polys = []
        feet = self.feet[i]
        if feet is not None:
            ang = np.linspace(0, 2 * np.pi, 17)[:-1]
            for p in feet[f]:
                if np.isfinite(p).all():
                    x = p[0] - c[0] + _DISC * np.cos(ang)
                    y = p[1] - c[1] + _DISC * np.sin(ang)
                    px, py, _ = proj3d.proj_transform(x, y, np.full_like(x, 0.002), self.axes[i].M)
                    polys.append(np.stack([px, py], axis=1))
        self.discs[i].set_verts(polys)

    def frame(self, f: int) -> np.ndarray:
        """(H, W, 3) uint8 picture of frame ``f``."""
        m = self.motion
        rel = self.path - np.append(self.centre[f], 0.0)
        rel[((rel[:, :2] < self.lo[:2]) | (rel[:, :2] > self.hi[:2])).any(1)] = np.nan  # inside the panel only
        for i, line in enumerate(self.paths):
            line.set_data_3d(rel[:, 0], rel[:, 1], np.full(len(rel), 0.001))
            self._floor(i, f)
        if self.ref_bones is not None:
            self.ref_bones.set_segments(_bones(self.ref_nodes[f], self.ref_skel.parents))
        g = self.goals[f]
        self.ref_dots.set_data_3d(g[:, 0], g[:, 1], g[:, 2])
        p = self.robot_pos[f]
        if self.mesh is not None:
            self.mesh.update(self.body_pos[f], self.body_rot[f])
        if self.rob_bones is not None:
            self.rob_bones.set_segments(_bones(p, m.skeleton.parents))
        if self.rob_dots is not None:
            self.rob_dots.set_data_3d(p[self.key, 0], p[self.key, 1], p[self.key, 2])
        self.label.set_text(f"frame {f + 1:>{len(str(m.num_frames))}d}/{m.num_frames}   t = {f / m.fps:6.2f} s")
        self.canvas.restore_region(self.background)
        for a in self.moving:
            if hasattr(a, "do_3d_projection"):
                a.do_3d_projection()  # 3D -> 2D with the panel's fixed camera
            (a.axes or self.fig).draw_artist(a)
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()


def _gif_durations(count: int, fps: float) -> list[int]:
    """Per-frame delays [ms], multiples of 10 (GIF stores centiseconds) whose sum keeps the true clock."""
    cs = np.round(np.arange(count + 1) * 100.0 / fps).astype(int)
    return [int(d) * 10 for d in np.maximum(np.diff(cs), 1)]


def _swatches() -> np.ndarray:
    """(N, 3) uint8: every colour drawn, at the shades the light gives it, so that one GIF palette
    holds what appears only in later frames (a contact mark, a turned face)."""
    shade = np.linspace(0.45, 1.0, 24)[:, None]
    ramps = [np.asarray(c)[None] * shade for c in (MESH_RGB, COLLISION_RGB)]
    flat = np.array([REFERENCE_RGB, CONTACT_RGB, FLOOR_RGB, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0)])
    return np.round(255 * np.concatenate([*ramps, flat])).astype(np.uint8)


def _write_gif(path: Path, frames, count: int, fps: float) -> Path:
    from PIL import Image

    images, palette = [], None
    for rgb in frames:
        im = Image.fromarray(rgb)
        if palette is None:  # one palette: the first frame and the swatches of every colour drawn
            sw, per_row = _swatches(), max(1, rgb.shape[1] // 8)  # 8 x 8 px each, rows as wide as the frame
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
    r = _Renderer(motion, robot_pos, goals, nodes, reference_skeleton if nodes is not None else None, (w, h), title, shown=idx,
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
