"""Drawing one frame of the retargeting video (:mod:`mer_models.export.video`, which encodes the frames):
two 3D matplotlib panels (Agg, no window), the scaled reference on the left, the robot on the right
(its meshes or collision shapes joined by bones, :func:`~mer_models.export.geometry.bone_segments`,
else its skeleton's bones), a floor grid that scrolls under a camera following the robot, feet in
contact marked on the floor. The panes, grids and titles are drawn once; each frame redraws only
what moves (blitting)."""

from __future__ import annotations

import numpy as np

from mer_data.skeleton import Skeleton

from .geometry import RobotMeshes, bone_segments
from .writers import TargetMotion

__all__ = ["VideoRenderer", "MESH_RGB", "COLLISION_RGB", "REFERENCE_RGB", "CONTACT_RGB", "FLOOR_RGB", "VIDEO_MAX_FACES", "swatches"]


def _bounds(*clouds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Low and high corners (3,) of every point, padded, with the floor (z = 0) included."""
    pts = np.concatenate([c.reshape(-1, 3) for c in clouds])
    lo, hi = pts.min(0), pts.max(0)
    lo[2] = min(lo[2], 0.0)
    pad = 0.05 * max(float((hi - lo).max()), 0.5)
    return lo - pad, hi + pad


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


class VideoRenderer:
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
            self.ref_bones = Line3DCollection(bone_segments(ref_nodes[0], ref_skel.parents), colors=[REFERENCE_RGB], linewidths=1.5)
            ref_ax.add_collection3d(self.ref_bones, autolim=False)
        (self.ref_dots,) = ref_ax.plot([], [], [], "o", color=REFERENCE_RGB, ms=3)
        self.rob_bones = self.rob_dots = None
        if self.mesh is None or meshes.kind != "mesh":  # bones: of a skeleton without a robot, or joining collision shapes
            colour, width = ("0.3", 1.5) if self.mesh is None else ("0.55", 2.5)  # not the meshes' blue
            self.rob_bones = Line3DCollection(bone_segments(robot_pos[0], skel.parents), colors=colour, linewidths=width)
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
            self.ref_bones.set_segments(bone_segments(self.ref_nodes[f], self.ref_skel.parents))
        g = self.goals[f]
        self.ref_dots.set_data_3d(g[:, 0], g[:, 1], g[:, 2])
        p = self.robot_pos[f]
        if self.mesh is not None:
            self.mesh.update(self.body_pos[f], self.body_rot[f])
        if self.rob_bones is not None:
            self.rob_bones.set_segments(bone_segments(p, m.skeleton.parents))
        if self.rob_dots is not None:
            self.rob_dots.set_data_3d(p[self.key, 0], p[self.key, 1], p[self.key, 2])
        self.label.set_text(f"frame {f + 1:>{len(str(m.num_frames))}d}/{m.num_frames}   t = {f / m.fps:6.2f} s")
        self.canvas.restore_region(self.background)
        for a in self.moving:
            if hasattr(a, "do_3d_projection"):
                a.do_3d_projection()  # 3D -> 2D with the panel's fixed camera
            (a.axes or self.fig).draw_artist(a)
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()


def swatches() -> np.ndarray:
    """(N, 3) uint8: every colour drawn, at the shades the light gives it, so that one GIF palette
    holds what appears only in later frames (a contact mark, a turned face)."""
    shade = np.linspace(0.45, 1.0, 24)[:, None]
    ramps = [np.asarray(c)[None] * shade for c in (MESH_RGB, COLLISION_RGB)]
    flat = np.array([REFERENCE_RGB, CONTACT_RGB, FLOOR_RGB, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0)])
    return np.round(255 * np.concatenate([*ramps, flat])).astype(np.uint8)
