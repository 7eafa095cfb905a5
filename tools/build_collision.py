"""Maintainer script: derive compact collision geometry for the built-in robots from upstream meshes.

For every ``<link>`` of ``mer_data/robots/builtin/<name>/<name>.urdf`` that has ``<collision>``
elements (as :func:`mer_data.robots.urdf.load_urdf` reads them), each element becomes one shape of
``collision.json`` beside the URDF, written by :func:`mer_data.robots.shapes.dump_collision`:

* ``box`` / ``sphere`` / ``cylinder``: kept as in the URDF, with the collision ``<origin>``;
* ``mesh`` (STL, DAE, OBJ): read from the upstream repository, scaled by ``<mesh scale>``, moved by the
  collision ``<origin>`` into the LINK frame, and replaced by its convex hull, simplified to at most
  ``--max-vertices`` (48) vertices by :func:`mer_data.robots.hulls.simplify_hull` (the same inner
  approximation registration uses), stopping early once every original hull vertex lies within
  ``--tol-mm`` of the simplified hull. Coordinates are rounded to 10 um (5 decimals); the error
  reported (and written into ``source``) is the largest distance from an original hull vertex to the
  simplified, rounded hull.

A mesh that cannot be found or read upstream puts its link under ``missing``; the build carries on.
The URDFs hold kinematics only; the meshes are NOT in this repository. Each upstream is given as a
checkout or as a git directory without a work tree (files are then read from ``--rev``, default HEAD,
with ``git cat-file``), keyed by its GitHub ``owner/name`` (or by a robot name, for one robot only).
A plain folder that is not a git repository works too; its commit is then written as ``unknown``.

Rebuild all eight (``UP`` holds the upstream checkouts or mirrors; the commits used are recorded in
``source``; the shipped files were built from the commits listed in ../shared/robots/SOURCES.md)::

    python tools/build_collision.py \\
        --source unitreerobotics/unitree_ros=$UP/unitree_ros \\
        --source osrf/drcsim=$UP/drcsim \\
        --source limxdynamics/humanoid-description=$UP/humanoid-description \\
        --source limxdynamics/robot-description=$UP/robot-description \\
        --source pal-robotics/talos_robot=$UP/talos_robot \\
        --source gkjohnson/nasa-urdf-robots=$UP/nasa-urdf-robots \\
        --check

or, with mirrors laid out as ``<DIR>/<owner>+<name>/repo`` (or ``<DIR>/<owner>+<name>``, ``<DIR>/<name>``)::

    python tools/build_collision.py --mirrors DIR [--robots g1 h1] [--check]

``--check`` also prints, per robot, the lowest point of all collision geometry at the zero pose (root
frame) and validates each file with :func:`mer_data.robots.shapes.parse_collision`.
"""

from __future__ import annotations

import argparse
import io
import math
import os
import re
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import QhullError

from mer_data.base.errors import MerError
from mer_data.robots.builder import zero_pose_link_transforms
from mer_data.robots.collision import shape_vertices
from mer_data.robots.hulls import simplify_hull
from mer_data.robots.shapes import CollisionFile, Shape, dump_collision, parse_collision, primitive_shape
from mer_data.robots.urdf import load_urdf

ROOT = Path(__file__).resolve().parents[1]
BUILTIN = ROOT / "mer_data" / "robots" / "builtin"


@dataclass(frozen=True)
class RobotSpec:
    """Where a built-in robot's collision meshes live upstream.

    Attributes:
        repo: GitHub ``owner/name`` of the upstream repository.
        urdf_dir: folder (in the repo) of the upstream URDF: relative mesh paths resolve against it.
        mesh_dir: the mesh folder, for the ``source`` line.
        packages: ROS package name -> candidate folders in the repo (``package://PKG/...``), first found wins.
    """

    repo: str
    urdf_dir: str
    mesh_dir: str
    packages: dict[str, tuple[str, ...]] = field(default_factory=dict)


ROBOTS: dict[str, RobotSpec] = {
    "g1": RobotSpec("unitreerobotics/unitree_ros", "robots/g1_description", "robots/g1_description/meshes",
                    {"g1_description": ("robots/g1_description",)}),
    "h1": RobotSpec("unitreerobotics/unitree_ros", "robots/h1_description/urdf", "robots/h1_description/meshes",
                    {"h1_description": ("robots/h1_description",)}),
    "h1_2": RobotSpec("unitreerobotics/unitree_ros", "robots/h1_2_description", "robots/h1_2_description/meshes",
                      {"h1_2_description": ("robots/h1_2_description",)}),
    "atlas": RobotSpec("osrf/drcsim", "atlas_description/robots", "atlas_description/meshes_unplugged",
                       {"atlas_description": ("atlas_description",),
                        "multisense_sl_description": ("multisense_sl_description",)}),
    "oli": RobotSpec("limxdynamics/humanoid-description", "HU_D04_description/urdf", "HU_D04_description/meshes",
                     {"HU_D04_description": ("HU_D04_description",)}),
    "tron1": RobotSpec("limxdynamics/robot-description", "pointfoot/SF_TRON1A/urdf", "pointfoot/SF_TRON1A/meshes",
                       {"robot_description": ("",)}),
    # Gepetto/example-robot-data robots/talos_data holds most of the same meshes (not ankle_X_collision.stl).
    "talos": RobotSpec("pal-robotics/talos_robot", "talos_description/robots", "talos_description/meshes",
                       {"talos_description": ("talos_description", "robots/talos_data")}),
    "valkyrie": RobotSpec("gkjohnson/nasa-urdf-robots", "val_description/model/robots", "val_description/model/meshes",
                          {"val_description": ("val_description",)}),
}  # fmt: skip


# ---- upstream files --------------------------------------------------------------------------------
class Upstream:
    """Files of one upstream repository: a checkout (read from disk) or a git dir without work tree."""

    def __init__(self, path: Path, rev: str = "HEAD") -> None:
        self.path = path
        self.rev = rev
        self.git = self._git("rev-parse", "--git-dir") is not None
        work_tree = self._git("rev-parse", "--is-inside-work-tree") if self.git else None
        self.bare = self.git and (work_tree or b"").strip() != b"true"  # no work tree: read blobs from git
        commit = self._git("rev-parse", f"{rev}^{{commit}}") if self.git else None
        self.commit = commit.decode().strip() if commit else "unknown"
        if self.git and not self.bare and rev != "HEAD":
            raise SystemExit(f"{path}: --rev {rev} needs a git dir without work tree (a checkout is read as it is)")

    def _git(self, *args: str) -> bytes | None:
        try:
            env = {**os.environ, "GIT_NO_LAZY_FETCH": "1"}  # a partial clone must not go to the network
            out = subprocess.run(["git", "-C", str(self.path), *args], capture_output=True, timeout=120, env=env)
        except (OSError, subprocess.TimeoutExpired):
            return None
        return out.stdout if out.returncode == 0 else None

    def read(self, rel: str) -> bytes | None:
        """The bytes of ``rel`` (a path inside the repository), or None when absent or unreadable."""
        rel = rel.strip("/")
        if self.bare:
            return self._git("cat-file", "blob", f"{self.rev}:{rel}")
        p = self.path / rel
        return p.read_bytes() if p.is_file() else None

    def exists(self, rel: str) -> bool:
        rel = rel.strip("/")
        if self.bare:
            return self._git("cat-file", "-e", f"{self.rev}:{rel}") is not None
        return (self.path / rel).exists()


def resolve_mesh(filename: str, spec: RobotSpec, up: Upstream) -> str | None:
    """Path inside the upstream repository of a URDF mesh reference, or None when not found there."""
    m = re.match(r"package://([^/]+)/(.*)", filename)
    if m:
        pkg, rest = m.groups()
        candidates = [f"{d}/{rest}".strip("/") for d in spec.packages.get(pkg, (pkg,))]
    elif filename.startswith("file://") or filename.startswith("/"):
        candidates = []  # absolute paths of someone's machine: nothing to resolve against
    else:
        candidates = [str(Path(spec.urdf_dir, filename))]
        candidates = [re.sub(r"[^/]+/\.\./", "", c) for c in candidates]  # fold "dir/../"
    for c in candidates:
        if up.exists(c):
            return c
    return None


# ---- geometry --------------------------------------------------------------------------------------
def mesh_vertices(data: bytes, ext: str) -> np.ndarray:
    """(N, 3) vertices used by the faces of a mesh file (STL, DAE, OBJ), node transforms applied, metres."""
    import trimesh

    unit = 1.0
    if ext == "dae":
        head = data[:20000].decode("utf-8", "replace")
        m = re.search(r"<unit\b[^>]*\bmeter\s*=\s*\"([^\"]+)\"", head)
        unit = float(m.group(1)) if m else 1.0
        up = re.search(r"<up_axis>\s*(\w+)\s*</up_axis>", head)
        if up and up.group(1) != "Z_UP":
            print(f"    note: DAE up_axis {up.group(1)} kept as written (ROS tools disagree on it)")
    loaded = trimesh.load(io.BytesIO(data), file_type=ext, force="scene", process=False)
    parts = []
    for node in loaded.graph.nodes_geometry:
        transform, name = loaded.graph[node]
        g = loaded.geometry[name]
        faces = getattr(g, "faces", None)
        if faces is None or len(faces) == 0:
            continue  # lines, points: no surface
        v = np.asarray(g.vertices, np.float64)[np.unique(faces)]
        parts.append(v @ transform[:3, :3].T + transform[:3, 3])
    if not parts:
        raise ValueError("no triangles")
    return np.concatenate(parts) * unit


# ---- URDF -> shapes --------------------------------------------------------------------------------
@dataclass
class LinkReport:
    link: str
    file: str
    hull_vertices: int
    kept: int
    error_m: float


@dataclass
class RobotResult:
    name: str
    data: CollisionFile
    reports: list[LinkReport]
    n_hulls: int = 0
    n_primitives: int = 0
    text: str = ""


def build_robot(name: str, up: Upstream, max_vertices: int, tol: float) -> RobotResult:
    """The collision shapes of one built-in robot: its URDF's ``<collision>`` elements as the package
    reads them (:attr:`mer_data.robots.urdf.UrdfModel.collisions`), meshes read from upstream."""
    spec = ROBOTS[name]
    urdf = load_urdf(BUILTIN / name / f"{name}.urdf")
    links: dict[str, list[Shape]] = {}
    missing: list[str] = []
    reports: list[LinkReport] = []
    cache: dict[str | None, np.ndarray | None] = {}
    for lname in urdf.links:
        shapes: list[Shape] = []
        for c in urdf.collisions.get(lname, ()):
            t = np.asarray(c["origin"], np.float64)
            prim = primitive_shape(c)
            if prim is not None:
                shapes.append(prim)
            else:
                rel = resolve_mesh(c["filename"], spec, up)
                if rel not in cache:
                    cache[rel] = None
                    data = up.read(rel) if rel else None
                    if data is None:
                        print(f"    {lname}: mesh {c['filename']} not found upstream")
                    else:
                        try:
                            cache[rel] = mesh_vertices(data, Path(rel).suffix.lower().lstrip("."))
                        except Exception as exc:  # noqa: BLE001 - any unreadable mesh is reported, not fatal
                            print(f"    {lname}: cannot read {rel}: {exc}")
                verts = cache[rel]
                if verts is not None:
                    pts = (verts * np.asarray(c["scale"])) @ t[:3, :3].T + t[:3, 3]
                    try:
                        hull, err, n_full = simplify_hull(pts, max_vertices, tol)
                    except (QhullError, ValueError) as exc:
                        print(f"    {lname}: {rel} has no 3-D convex hull ({str(exc).splitlines()[0]})")
                        verts = None
                if verts is None:
                    if lname not in missing:
                        missing.append(lname)
                    continue
                reports.append(LinkReport(lname, rel or c["filename"], n_full, len(hull), err))
                shapes.append(Shape("hull", np.eye(4), vertices=hull, source="mesh"))
        if shapes:
            links[lname] = shapes
    if reports:
        worst = max(reports, key=lambda r: r.error_m)
        how = (f"meshes as convex hulls of at most {max_vertices} vertices (inner approximation, worst error "
               f"{worst.error_m * 1000:.2f} mm on link {worst.link})")  # fmt: skip
    else:
        how = "no meshes among the URDF's collision elements"
    cf = CollisionFile(name, {k: tuple(v) for k, v in links.items()}, f"{spec.repo}@{up.commit} {spec.mesh_dir}; {how}; primitives as in the URDF",
                       tuple(missing))  # fmt: skip
    n_hulls = sum(s.type == "hull" for v in links.values() for s in v)
    return RobotResult(name, cf, reports, n_hulls, sum(len(v) for v in links.values()) - n_hulls, dump_collision(cf))


# ---- checks ----------------------------------------------------------------------------------------
def lowest_point(name: str, cf: CollisionFile) -> tuple[float, str]:
    """Lowest z [m] of all collision geometry at the zero pose, in the root frame, and its link (the
    polytopes the metrics use: curved primitives circumscribed)."""
    t_root = zero_pose_link_transforms(load_urdf(BUILTIN / name / f"{name}.urdf"))
    best = (math.inf, "")
    for lname, shapes in cf.links.items():
        t = t_root[lname]
        for sh in shapes:
            z = float((shape_vertices(sh) @ t[:3, :3].T + t[:3, 3])[:, 2].min())
            if z < best[0]:
                best = (z, lname)
    return best


def validate(text: str, path: str) -> str:
    """Parse ``text`` with the project's reader; '' if it reads, else the error."""
    try:
        parse_collision(text, path)
    except MerError as exc:
        return str(exc)
    return ""


# ---- main ------------------------------------------------------------------------------------------
def parse_sources(args: argparse.Namespace) -> dict[str, Path]:
    """Robot name -> upstream folder, from --source (by repo or robot) and --mirrors."""
    by_key: dict[str, Path] = {}
    for item in args.source:
        key, sep, path = item.partition("=")
        if not sep:
            raise SystemExit(f"--source wants KEY=PATH (KEY: owner/name or a robot), got {item!r}")
        by_key[key] = Path(path).expanduser()
    out: dict[str, Path] = {}
    for name, spec in ROBOTS.items():
        if name in by_key:
            out[name] = by_key[name]
        elif spec.repo in by_key:
            out[name] = by_key[spec.repo]
        elif args.mirrors:
            owner, repo = spec.repo.split("/")
            for cand in (args.mirrors / f"{owner}+{repo}" / "repo", args.mirrors / f"{owner}+{repo}", args.mirrors / repo):
                if cand.is_dir():
                    out[name] = cand
                    break
    return out


def add_source_args(ap: argparse.ArgumentParser) -> None:
    """``--source``, ``--mirrors`` and ``--rev``: where the upstream repositories are (:func:`parse_sources`)."""
    ap.add_argument(
        "--source",
        action="append",
        default=[],
        metavar="KEY=PATH",
        help="upstream checkout or git dir; KEY is its GitHub owner/name or a robot name (repeatable)",
    )
    ap.add_argument("--mirrors", type=Path, help="folder of mirrors <owner>+<name>/repo (for repos not given by --source)")
    ap.add_argument("--rev", default="HEAD", help="revision to read from git dirs without work tree (default HEAD)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    add_source_args(ap)
    ap.add_argument("--robots", nargs="+", choices=sorted(ROBOTS), default=list(ROBOTS))
    ap.add_argument("--max-vertices", type=int, default=48, help="vertex budget of a hull (default 48)")
    ap.add_argument(
        "--tol-mm",
        type=float,
        default=0.0,
        help="stop adding hull vertices once the error is below this [mm] (default 0: use the budget)",
    )
    ap.add_argument(
        "--out-dir", type=Path, default=BUILTIN, help="write <out-dir>/<name>/collision.json (default: the built-ins)"
    )
    ap.add_argument("--dry-run", action="store_true", help="build and report, write nothing")
    ap.add_argument("--check", action="store_true", help="also report the zero-pose lowest point and validate each file")
    args = ap.parse_args(argv)

    sources = parse_sources(args)
    absent = [n for n in args.robots if n not in sources]
    if absent:
        raise SystemExit(f"no upstream given for: {', '.join(absent)} (use --source owner/name=PATH or --mirrors DIR)")
    ups: dict[Path, Upstream] = {}
    total = 0
    rows = []
    for name in args.robots:
        path = sources[name]
        up = ups.setdefault(path, Upstream(path, args.rev))
        print(f"{name}: {ROBOTS[name].repo}@{up.commit} ({path})")
        res = build_robot(name, up, args.max_vertices, args.tol_mm * 1e-3)
        size = len(res.text.encode("utf-8"))
        total += size
        worst = max(res.reports, key=lambda r: r.error_m, default=None)
        for r in sorted(res.reports, key=lambda r: -r.error_m)[:3]:
            print(f"    error {r.error_m * 1000:6.2f} mm  {r.link:32s} {r.kept:3d}/{r.hull_vertices:4d} hull vertices  {r.file}")
        line = (f"  {name:9s} links {len(res.data.links):3d}  hulls {res.n_hulls:3d}  primitives {res.n_primitives:3d}  "
                f"missing {len(res.data.missing):2d}  worst {worst.error_m * 1000 if worst else 0:5.2f} mm "
                f"({worst.link if worst else '-'})  {size / 1024:6.1f} KiB")  # fmt: skip
        if args.check:
            z, link = lowest_point(name, res.data)
            problem = validate(res.text, f"{name}/collision.json")
            line += f"  lowest z {z:+.4f} m on {link}" + (f"  INVALID: {problem}" if problem else "  (reads back)")
        rows.append(line)
        if not args.dry_run:
            out = args.out_dir / name / "collision.json"
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(res.text, encoding="utf-8")
    print("\n".join(["summary:", *rows, f"  total {total / 1024:.1f} KiB"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
