"""Maintainer script: compact visual meshes for the built-in robots, decimated from the upstream meshes.

For each built-in robot whose licence allows redistributing modified meshes (:data:`SHIPPED`), every
``<visual>`` mesh of ``mer_data/robots/builtin/<name>/<name>.urdf`` is read from the upstream
repository (the same sources and package folders as ``tools/build_collision.py``; DAE units and node
transforms applied, so a shipped file is in metres), decimated (:func:`simplify`: per file the
nearer to the upstream surface of quadric edge collapse -- ``fast-simplification``, the ``[tools]``
extra, not a runtime dependency -- and mer's own vertex clustering) and written as binary STL
to ``builtin/<name>/visual/`` (an upstream STL keeps its name; a DAE becomes ``<stem>.stl``). The robot's face budget (``--faces``) is shared by its mesh
files in proportion to their surface area (each keeps at least ``--min-faces``; a file under its
share keeps all its faces); the budget is lowered until the robot's files, together, are at most
``--max-bytes`` (1 MB). Each visual ``<mesh filename>`` of the URDF is then rewritten to
``visual/<file>``, nothing else in it: ``<collision>`` elements and the kinematics stay byte for
byte (the built-ins' collision geometry is ``collision.json``), and ``visual/`` matches no upstream
collision path, so no collision reference can resolve to a shipped visual mesh.

Beside the meshes: ``visual/LICENSE`` (the robot's licence text, copied) and ``visual/sources.json``
(each shipped file's upstream path, commit and face counts; a rerun reads the upstream path from it
once the URDF has been rewritten). Rebuild (mirrors laid out as for ``tools/build_collision.py``)::

    pip install -e .[tools]
    python tools/build_meshes.py --mirrors DIR [--robots g1 h1] [--check]

``--check`` draws each robot as ``mer view`` does (:func:`mer_models.export.geometry.robot_meshes`)
and prints what draws it, the mesh files not found, and, per body, how far the centre of its visual
meshes' box is from its collision shapes' box (a wrong unit or frame shows up as centimetres).

Not shipped: :data:`NOT_SHIPPED` says why.
"""

from __future__ import annotations

import argparse
import io
import json
import re
import shutil
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from build_collision import BUILTIN, ROBOTS, RobotSpec, Upstream, add_source_args, parse_sources, resolve_mesh  # noqa: E402

#: Built-ins whose meshes are shipped, with the licence that allows it.
SHIPPED = {
    "g1": "BSD-3-Clause (unitreerobotics/unitree_ros LICENSE)",
    "h1": "BSD-3-Clause (unitreerobotics/unitree_ros LICENSE)",
    "h1_2": "BSD-3-Clause (unitreerobotics/unitree_ros LICENSE)",
    "oli": "Apache-2.0 (limxdynamics/humanoid-description LICENSE)",
    "tron1": "Apache-2.0 (limxdynamics/robot-description LICENSE)",
    "atlas": "Apache-2.0 (osrf/drcsim atlas_description and multisense_sl_description package.xml)",
    "talos": "Apache-2.0 (pal-robotics/talos_robot LICENSE since b3240d10, 2023; the meshes carry no other notice)",
}
#: Built-ins whose meshes are not shipped, and why.
NOT_SHIPPED = {
    "valkyrie": "NASA-1.3: redistributing modified files needs the agreement's full text beside them and each "
                "modification marked as such; the upstream carries neither the text nor a statement for the "
                "meshes, and NASA-1.3 is incompatible with GPL-licensed users of the package",
}  # fmt: skip
#: Package names the upstream URDFs use that ``build_collision.ROBOTS`` does not map (Atlas's head).
EXTRA_PACKAGES = {"atlas": {"atlas": ("atlas_description",)}}
FOLDER = "visual"
STL_HEADER = 80
STL_FACE = 50  # bytes per face of a binary STL


# ---- upstream meshes -------------------------------------------------------------------------------
def mesh_triangles(data: bytes, ext: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) [m] and triangles (T, 3) of an upstream mesh file (STL, DAE, OBJ): node
    transforms and a DAE's ``<unit meter>`` applied, duplicate vertices merged."""
    import trimesh

    unit = 1.0
    if ext == "dae":
        m = re.search(r"<unit\b[^>]*\bmeter\s*=\s*\"([^\"]+)\"", data[:20000].decode("utf-8", "replace"))
        unit = float(m.group(1)) if m else 1.0
    scene = trimesh.load(io.BytesIO(data), file_type=ext, force="scene", process=False)
    vs, fs, n = [], [], 0
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        g = scene.geometry[name]
        faces = getattr(g, "faces", None)
        if faces is None or len(faces) == 0:
            continue  # lines, points: no surface
        v = np.asarray(g.vertices, np.float64) @ transform[:3, :3].T + transform[:3, 3]
        vs.append(v)
        fs.append(np.asarray(faces, np.int64) + n)
        n += len(v)
    if not vs:
        raise ValueError("no triangles")
    mesh = trimesh.Trimesh(np.concatenate(vs) * unit, np.concatenate(fs), process=True)  # merges STL's repeated vertices
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)


def area(v: np.ndarray, f: np.ndarray) -> float:
    return float(0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum())


def allocate(faces: list[int], areas: list[float], budget: int, floor: int) -> list[int]:
    """Faces per file: ``budget`` shared in proportion to ``areas``, each at least ``floor`` (or all
    it has), none more than it has; what a small file leaves is shared again by the others."""
    n = np.asarray(faces, np.int64)
    a = np.maximum(np.asarray(areas, np.float64), 1e-12)
    out = np.minimum(n, floor)
    free = np.ones(len(n), bool)
    for _ in range(len(n) + 1):
        left = budget - out[~free].sum() - np.minimum(n[free], floor).sum()
        share = np.maximum(np.floor(left * a / a[free].sum()), 0).astype(np.int64)
        want = np.where(free, np.minimum(n, np.maximum(share, floor)), out)
        capped = free & (want >= n)
        out = want
        if not capped.any():
            break
        free &= ~capped
        if not free.any():
            break
    return [int(x) for x in out]


def weld(v: np.ndarray, f: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertices within the same ``tol`` [m] grid cell merged (the first kept), faces that collapse dropped."""
    _, first, idx = np.unique(np.round(v / tol).astype(np.int64), axis=0, return_index=True, return_inverse=True)
    f = idx.ravel()[f]
    return v[first], f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]


#: Weld tolerances [m] tried in turn where quadric collapse stops short of the target (it refuses
#: collapses along seams of vertices that are near but not equal, as CAD exports write them).
WELDS = (0.0, 1e-4, 2.5e-4, 5e-4, 1e-3, 2e-3)


def surface_distance(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], samples: int = 400) -> float:
    """The symmetric Hausdorff distance [m] between two meshes, estimated on ``samples`` seeded
    surface points of each (the farthest sample of one from the other's surface)."""
    import trimesh

    ma, mb = trimesh.Trimesh(*a, process=False), trimesh.Trimesh(*b, process=False)
    worst = 0.0
    for src, dst in ((ma, mb), (mb, ma)):
        _, d, _ = trimesh.proximity.closest_point(dst, src.sample(samples, seed=1))
        worst = max(worst, float(np.max(d)))
    return worst


def volume(v: np.ndarray, f: np.ndarray) -> float:
    """Signed volume [m^3] enclosed by the faces (negative: the surface is mostly inside out)."""
    return float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6)


#: A decimated mesh keeps its volume within this factor of upstream's (vertex clustering or quadric
#: collapse at a few dozen faces can turn a thin part inside out: G1's wrists, Oli's elbows, volume < 0).
VOLUME_RATIO = (0.5, 1.5)
#: How many times a file's target grows by half where no decimation keeps its volume.
GROW = 4


def simplify(v: np.ndarray, f: np.ndarray, target: int) -> tuple[np.ndarray, np.ndarray, str, float]:
    """About ``target`` faces (10 % over allowed): of quadric edge collapse (``fast-simplification``;
    welded first by the smallest of :data:`WELDS` that lets it get there) and vertex clustering
    (:func:`mer_models.export.geometry.decimate`, what the viewer thins with), the one nearer the
    upstream surface (:func:`surface_distance`) among those that keep its volume
    (:data:`VOLUME_RATIO`; a closed upstream mesh only). Where neither does, the target grows by
    half, at most :data:`GROW` times, then the nearer is taken. Unused vertices dropped; also returns
    how it was made and its distance [m]."""
    import fast_simplification

    from mer_models.export.geometry import decimate

    v0 = volume(v, f)
    for grow in range(GROW + 1):
        if len(f) <= target:
            break
        found: list[tuple[float, bool, str, np.ndarray, np.ndarray]] = []
        for tol in WELDS:
            vw, fw = weld(v, f, tol) if tol else (v, f)
            vs, fs = fast_simplification.simplify(vw, fw.astype(np.int32), target_count=target, agg=7.0)
            if len(fs) <= 1.1 * target:
                used, fs = np.unique(np.asarray(fs, np.int64), return_inverse=True)
                found.append(
                    (0.0, False, f"quadric, weld {tol * 1000:g} mm", np.asarray(vs, np.float64)[used], fs.reshape(-1, 3))
                )
                break
        found.append((0.0, False, "vertex clustering", *decimate(v, f, target)))
        found = [(surface_distance((v, f), (vs, fs)), v0 <= 0 or VOLUME_RATIO[0] <= volume(vs, fs) / v0 <= VOLUME_RATIO[1], how, vs, fs)
                 for _, _, how, vs, fs in found]  # fmt: skip
        good = [x for x in found if x[1]]
        if good or grow == GROW:
            err, _, how, vs, fs = min(good or found, key=lambda x: x[0])
            return vs, fs, how + ("" if good else ", volume not kept"), err
        target = int(target * 1.5) + 1
    return v, f, "upstream", 0.0


def stl_bytes(v: np.ndarray, f: np.ndarray, header: str) -> bytes:
    """A binary STL of the mesh (float32; outward normals from the winding, zero where degenerate)."""
    tri = v[f].astype(np.float32)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).astype(np.float64)
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.where(length > 0, normal / np.where(length > 0, length, 1.0), 0.0).astype(np.float32)
    rec = np.zeros(len(f), np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")]))
    rec["n"], rec["v"] = normal, tri
    head = header.encode("ascii", "replace")[:STL_HEADER].ljust(STL_HEADER, b" ")
    return head + np.uint32(len(f)).tobytes() + rec.tobytes()


# ---- the URDF's visual meshes ----------------------------------------------------------------------
def visual_mesh_lines(urdf: Path) -> list[tuple[int, str, np.ndarray]]:
    """(line number, filename as written, scale) of each ``<visual>`` mesh of ``urdf`` (comments skipped)."""
    from lxml import etree

    root = etree.parse(str(urdf), etree.XMLParser(resolve_entities=False, no_network=True, remove_comments=True)).getroot()
    out = []
    for mesh in root.iterfind("link/visual/geometry/mesh"):
        scale = np.asarray([float(x) for x in (mesh.get("scale") or "1 1 1").split()], np.float64)
        out.append((mesh.sourceline, mesh.get("filename"), np.abs(np.broadcast_to(scale, (3,)))))
    return out


def shipped_name(rel: str, taken: dict[str, str]) -> str:
    """The shipped file name of the upstream path ``rel``: an STL keeps its upstream name (so a
    folder of the upstream meshes given as ``mesh_dir`` still matches it by name), another format
    becomes ``<stem>.stl``; the parent folder's name is prefixed where two upstream files would share
    a name."""
    name = Path(rel).name if Path(rel).suffix.lower() == ".stl" else Path(rel).stem + ".stl"
    if taken.get(name.lower(), rel) != rel:  # case-insensitive file systems
        name = f"{Path(rel).parent.name}_{name}"
    taken[name.lower()] = rel
    return name


def rewrite_urdf(text: str, refs: dict[int, tuple[str, str]]) -> str:
    """``text`` with the visual mesh filename on each line of ``refs`` (line → (old, new)) replaced."""
    lines = text.split("\n")
    for line, (old, new) in refs.items():
        if old == new:
            continue  # written by an earlier run
        before = lines[line - 1]
        after = before.replace(f'filename="{old}"', f'filename="{new}"', 1)
        if after == before:
            raise SystemExit(f"line {line}: filename={old!r} is not written as expected; edit the URDF by hand")
        lines[line - 1] = after
    return "\n".join(lines)


def build_robot(name: str, up: Upstream, budget: int, floor: int, max_bytes: int, out_dir: Path, dry_run: bool) -> str:
    """Decimate, write and rewrite one robot; a summary line."""
    spec = ROBOTS[name]
    spec = RobotSpec(spec.repo, spec.urdf_dir, spec.mesh_dir, {**spec.packages, **EXTRA_PACKAGES.get(name, {})})
    folder = BUILTIN / name
    urdf = folder / f"{name}.urdf"
    old = folder / FOLDER / "sources.json"
    known = json.loads(old.read_text())["files"] if old.is_file() else {}
    refs = visual_mesh_lines(urdf)
    taken: dict[str, str] = {}
    files: dict[str, dict] = {}  # shipped name -> record
    meshes: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    rewrite: dict[int, tuple[str, str]] = {}
    missing: list[str] = []
    for line, filename, scale in refs:
        shipped = filename[len(FOLDER) + 1 :] if filename.startswith(f"{FOLDER}/") else None
        rel = known[shipped]["upstream"] if shipped in known else resolve_mesh(filename, spec, up)
        if rel is None:
            missing.append(filename)
            continue
        name_out = next((k for k, r in files.items() if r["upstream"] == rel), None)
        if name_out is None:
            data = up.read(rel)
            try:
                v, f = mesh_triangles(data, Path(rel).suffix.lower().lstrip("."))
            except Exception as exc:  # noqa: BLE001 - an unreadable upstream mesh is reported, the build goes on
                print(f"    {filename}: cannot read {rel}: {exc}")
                missing.append(filename)
                continue
            name_out = shipped_name(rel, taken)
            meshes[name_out] = (v, f)
            files[name_out] = {"upstream": rel, "faces_upstream": len(f), "area_m2": area(v * scale, f)}
        rewrite[line] = (filename, f"{FOLDER}/{name_out}")
    names = list(files)
    total = max_bytes + 1
    while True:
        alloc = allocate([files[n]["faces_upstream"] for n in names], [files[n]["area_m2"] for n in names], budget, floor)
        out = {n: simplify(*meshes[n], k) for n, k in zip(names, alloc)}
        if budget < len(names) * floor:
            raise SystemExit(f"{name}: {max_bytes} bytes do not hold {len(names)} files of {floor} faces; lower --min-faces")
        blobs = {n: stl_bytes(*out[n][:2], f"mer tools/build_meshes.py: {spec.repo}@{up.commit[:12]} {files[n]['upstream']}")
                 for n in names}  # fmt: skip
        total = sum(len(b) for b in blobs.values())
        if total <= max_bytes:
            break
        budget = int(budget * max_bytes / total * 0.98)
    faces = 0
    for n in names:
        files[n]["faces"] = len(out[n][1])
        files[n]["bytes"] = len(blobs[n])
        files[n]["method"] = out[n][2]
        files[n]["distance_mm"] = round(out[n][3] * 1000, 2)
        files[n]["area_m2"] = round(files[n]["area_m2"], 6)
        faces += len(out[n][1])
    manifest = {"robot": name, "repo": spec.repo, "commit": up.commit, "licence": SHIPPED[name], "tool": "tools/build_meshes.py",
                "decimation": "per file the nearer to upstream (symmetric Hausdorff distance on 400 surface samples each way, distance_mm) of quadric edge collapse (fast-simplification, agg 7) and vertex clustering (mer_models.export.geometry.decimate)", "face_budget": budget, "faces": faces,
                "bytes": total, "missing": missing, "files": {n: files[n] for n in sorted(names)}}  # fmt: skip
    if not dry_run:
        dest = out_dir / name / FOLDER
        dest.mkdir(parents=True, exist_ok=True)
        for stale in [p for p in dest.iterdir() if p.suffix.lower() == ".stl"]:
            if stale.name not in blobs:
                stale.unlink()
        for n, b in blobs.items():
            (dest / n).write_bytes(b)
        shutil.copyfile(folder / "LICENSE", dest / "LICENSE")
        (dest / "sources.json").write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
        text = urdf.read_bytes().decode("utf-8")  # bytes: line ends (CRLF in some upstreams) kept as they are
        (out_dir / name / urdf.name).write_bytes(rewrite_urdf(text, rewrite).encode("utf-8"))
    upstream = sum(r["faces_upstream"] for r in files.values())
    dist = sorted(r["distance_mm"] for r in files.values())
    quadric = sum(r["method"].startswith("quadric") for r in files.values())
    lost = [n for n, r in files.items() if r["method"].endswith("volume not kept")]
    return (f"  {name:9s} files {len(names):3d}  faces {upstream:8d} -> {faces:6d}  {total / 1e6:5.3f} MB  "
            f"quadric {quadric:2d} clustering {sum(r['method'].startswith('vertex clustering') for r in files.values()):2d}  "
        f"volume not kept {len(lost)}{' (' + ', '.join(lost) + ')' if lost else ''}  "
            f"distance median {dist[len(dist) // 2] if dist else 0:5.1f} max {dist[-1] if dist else 0:5.1f} mm  "
            f"missing {len(missing)}{' (' + ', '.join(missing) + ')' if missing else ''}")  # fmt: skip


def check(name: str) -> str:
    """What draws the built-in ``name`` as ``mer view`` does, and the worst body's distance between
    its visual meshes' box centre and its collision shapes' box centre [cm]."""
    from mer_data.robots.registry import as_robot
    from mer_models.export.geometry import robot_meshes

    robot = as_robot(name)
    vis = robot_meshes(robot, max_faces=None)
    col = {b.body: b for b in robot_meshes(robot, visual=False, max_faces=None).bodies}
    gaps = []
    for b in vis.bodies:
        if b.source == "mesh" and b.body in col:
            c = col[b.body].vertices
            gaps.append((np.linalg.norm((b.vertices.min(0) + b.vertices.max(0)) / 2 - (c.min(0) + c.max(0)) / 2) * 100,
                         vis.body_names[b.body]))  # fmt: skip
    worst = max(gaps, default=(0.0, "-"))
    drawn = sum(b.source == "mesh" for b in vis.bodies)
    return (f"  {name:9s} draws {vis.kind}: {drawn}/{len(vis.bodies)} bodies by mesh, {vis.num_faces} faces, "
            f"missing {len(vis.missing)}; box centres visual vs collision: median {np.median([g for g, _ in gaps]) if gaps else 0:.1f} cm, "
            f"worst {worst[0]:.1f} cm ({worst[1]})")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    add_source_args(ap)
    ap.add_argument("--robots", nargs="+", choices=sorted(SHIPPED), default=list(SHIPPED))
    ap.add_argument("--faces", type=int, default=16000, help="face budget of one robot (default 16000)")
    ap.add_argument("--min-faces", type=int, default=48, help="faces a mesh file keeps at least (default 48)")
    ap.add_argument("--max-bytes", type=int, default=1_000_000, help="bytes of one robot's meshes at most (default 1 MB)")
    ap.add_argument("--out-dir", type=Path, default=BUILTIN, help="write <out-dir>/<name>/ (default: the built-ins)")
    ap.add_argument("--dry-run", action="store_true", help="build and report, write nothing")
    ap.add_argument("--check", action="store_true", help="then draw each robot as `mer view` does and report")
    args = ap.parse_args(argv)  # fmt: skip

    sources = parse_sources(args)
    absent = [n for n in args.robots if n not in sources]
    if absent:
        raise SystemExit(f"no upstream given for: {', '.join(absent)} (use --source owner/name=PATH or --mirrors DIR)")
    ups: dict[Path, Upstream] = {}
    rows = []
    for name in args.robots:
        up = ups.setdefault(sources[name], Upstream(sources[name], args.rev))
        print(f"{name}: {ROBOTS[name].repo}@{up.commit} ({sources[name]})")
        rows.append(build_robot(name, up, args.faces, args.min_faces, args.max_bytes, args.out_dir, args.dry_run))
    print("\n".join(["summary:", *rows, *(f"  {n:9s} not shipped: {why}" for n, why in NOT_SHIPPED.items())]))
    if args.check and not args.dry_run and args.out_dir == BUILTIN:
        print("\n".join(["check:", *(check(n) for n in args.robots)]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
