"""The feet of human sources on robots (issue 49): a table of what a tracker needs from the stance feet.

Retargets every human clip of a folder (BVH, SMPL .npz, joint .npy; the file's kind from its
content) to each target with the default command's path (the optimiser with a human source's
physical terms, :func:`mer_models.retarget.clip.human_physics`, and the robot's collision geometry;
``--physics penalty|constraints`` for a method's own defaults), then measures, on the robot's collision polytopes (floor z = 0)
and in the frames where the *human's* foot of the same side is down
(:func:`mer_data.motion.contacts.foot_contacts` on the source):

* ``skate``: the horizontal speed of the robot foot's lowest body-fixed point (the vertex lowest at
  frame t, followed to t + 1) [cm/s]: median over all such frame pairs of all clips, and the share
  over 5 cm/s; next to the human's own: the lowest sole point's horizontal speed in its contact
  frames (median);
* ``sole<=1cm``: share of those frames in which the robot foot's lowest point is within 1 cm of
  the floor (above or below);
* ``floor``: share of all frames with a foot below -1 cm; ``limits``: share of frames with a joint
  outside its URDF limits; ``speed``: share of frame pairs with a joint over its velocity limit.

Usage (nice it, it is long: a few seconds per clip and target on 2 cores)::

    nice -n 10 python tools/human_feet.py ../shared/data/bvh/bandai1 --targets g1 h1 [--every 10] [--hz120 TMPDIR]

``--accuracy`` instead prints the key-point error (g-mpbpe against the human scaled to the robot),
jerk and time of the penalty terms and of a human source's physics, in one run.

``--hz120 TMPDIR`` also writes a 120 Hz copy of each BVH there (channels linearly interpolated,
angles unwrapped first; a temporary folder, never committed) and measures it too.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mer_data.kinematics.collision import shape_points  # noqa: E402
from mer_data.motion.contacts import foot_contacts  # noqa: E402
from mer_data.motion.features import split_features  # noqa: E402
from mer_data.motion.sources import SOURCE_FPS, human_kind, read_source  # noqa: E402
from mer_data.robots.collision import collision_model  # noqa: E402
from mer_data.robots.registry import load_robot  # noqa: E402
from mer_models.retarget.clip import retarget_features  # noqa: E402
from mer_models.solver.physics import PhysicsConfig  # noqa: E402


def write_120hz(path: Path, out_dir: Path) -> Path:
    """A 120 Hz copy of a BVH (frame values linearly interpolated, rotation channels unwrapped)."""
    text = path.read_text(encoding="utf-8", errors="replace").splitlines()
    i = next(k for k, line in enumerate(text) if line.strip().lower().startswith("frame time"))
    fps = 1.0 / float(text[i].split(":")[1])
    vals = np.array([[float(v) for v in line.split()] for line in text[i + 1 :] if line.strip()])
    names = [c for line in text[:i] if line.strip().upper().startswith("CHANNELS") for c in line.split()[2:]]
    rot = np.array(["rotation" in c.lower() for c in names])
    vals[:, rot] = np.rad2deg(np.unwrap(np.deg2rad(vals[:, rot]), axis=0))
    k = int(round(120.0 / fps))
    t = np.arange((len(vals) - 1) * k + 1) / k
    up = np.stack([np.interp(t, np.arange(len(vals)), vals[:, c]) for c in range(vals.shape[1])], 1)
    head = text[: i - 1] + [f"Frames: {len(up)}", f"Frame Time: {1.0 / (fps * k):.10f}"]
    out = out_dir / path.name
    out.write_text("\n".join(head + [" ".join(f"{v:.6f}" for v in row) for row in up]) + "\n")
    return out


def measure(path: Path, robot, model, physics) -> dict:
    src = read_source(path, human_kind(path, None))
    feats = src.features()
    res = retarget_features(feats, src.skeleton, robot.skeleton, method="optimize", physics=physics, geometry=[model])
    pos, rot = res.motion.forward_kinematics()
    pos_t, rot_t = torch.from_numpy(np.asarray(pos, np.float64)), torch.from_numpy(np.asarray(rot, np.float64))
    F = pos_t.shape[0]
    verts = shape_points(model, pos_t, rot_t, "vertices")
    z = verts[..., 2]
    low_z, low_v = z.min(-1)
    ref_pos = split_features(torch.from_numpy(feats))["pos"].numpy()
    contacts = foot_contacts(ref_pos, src.skeleton, SOURCE_FPS)  # (F, 2) human's left, right
    foot = torch.as_tensor(model.foot)
    out = {"skate": [], "human": [], "sole": [], "frames": F}
    foot_lows = []
    for side in (1, 2):
        f = torch.nonzero(foot == side).flatten()
        if not len(f):
            continue
        lz, which = low_z[:, f].min(-1)
        foot_lows.append(lz)
        s_idx = f[which]
        v_idx = low_v[torch.arange(F), s_idx]
        p_now = verts[torch.arange(F - 1), s_idx[:-1], v_idx[:-1]]
        p_next = verts[torch.arange(1, F), s_idx[:-1], v_idx[:-1]]
        down = torch.from_numpy(contacts[:, side - 1])
        pair = down[:-1] & down[1:]
        out["skate"].append(((p_next[:, :2] - p_now[:, :2]).norm(dim=-1) * SOURCE_FPS)[pair].numpy())
        out["sole"].append((lz.abs() <= 0.01)[down].numpy())
    # the human's own sole speed in contact
    from mer_data.motion.contacts import sole_points

    for i, nodes in enumerate(sole_points(src.skeleton).values()):
        zz = ref_pos[:, nodes, 2]
        low = zz.argmin(1)
        xy = ref_pos[:, nodes, :2][np.arange(F), low]
        nxt = ref_pos[np.minimum(np.arange(F) + 1, F - 1)][:, nodes, :2][np.arange(F), low]
        pair = contacts[:-1, i] & contacts[1:, i]
        out["human"].append((np.linalg.norm(nxt - xy, axis=1) * SOURCE_FPS)[:-1][pair])
    fl = torch.stack(foot_lows, -1).min(-1).values if foot_lows else torch.zeros(F)
    out["floor"] = int((fl < -0.01).sum())
    sk = robot.skeleton
    a = np.asarray(res.motion.q, np.float64)[:, : sk.num_nodes]
    rev = sk.revolute_mask & ~np.asarray(sk.continuous, bool)
    out["limits"] = int(((a[:, rev] < sk.lower[rev] - 1e-6) | (a[:, rev] > sk.upper[rev] + 1e-6)).any(1).sum())
    lim = np.asarray(model.velocity_limit, np.float64)
    has = np.isfinite(lim) & (lim > 0)
    if has.any() and len(a) > 1:
        out["speed"] = int(((np.abs(np.diff(a, axis=0))[:, has] * SOURCE_FPS) > lim[has]).any(1).sum())
    return out


def table(files: list[Path], targets: list[str], label: str, physics) -> None:
    print(f"\n{label}: {len(files)} clips")
    print(f"{'target':8s} {'skate med[cm/s]':>15s} {'human toe[cm/s]':>15s} {'ratio':>6s} {'>5cm/s':>7s} {'sole<=1cm':>9s} "
          f"{'floor<-1cm':>10s} {'limits':>7s} {'speed':>7s} {'s':>6s}")  # fmt: skip
    for name in targets:
        robot = load_robot(name)
        model = collision_model(robot)
        agg = {"skate": [], "human": [], "sole": [], "floor": 0, "limits": 0, "speed": 0, "frames": 0}
        t0 = time.perf_counter()
        for f in files:
            m = measure(f, robot, model, physics)
            for k in ("skate", "human", "sole"):
                agg[k] += m[k]
            for k in ("floor", "limits", "speed", "frames"):
                agg[k] += m[k]
        sk = np.concatenate(agg["skate"]) * 100
        hu = np.concatenate(agg["human"]) * 100
        so = np.concatenate(agg["sole"])
        med, hmed = float(np.median(sk)) if len(sk) else math.nan, float(np.median(hu)) if len(hu) else math.nan
        print(f"{name:8s} {med:15.1f} {hmed:15.1f} {med / max(hmed, 1e-9):6.2f} {float((sk > 5).mean()):7.1%} "
              f"{float(so.mean()):9.1%} {agg['floor'] / agg['frames']:10.2%} {agg['limits'] / agg['frames']:7.2%} "
              f"{agg['speed'] / agg['frames']:7.2%} {time.perf_counter() - t0:6.0f}", flush=True)  # fmt: skip


def accuracy(files: list[Path], targets: list[str]) -> None:
    """g-mpbpe (key points against the human scaled to the robot) [mm], jerk and time of the penalty
    terms against a human source's physics, both in this run."""
    from mer_data.kinematics.jointmap import joint_map
    from mer_models.retarget.clip import human_physics

    print(f"\nkey points, {len(files)} clips: penalty against human_physics()")
    for name in targets:
        robot = load_robot(name)
        model = collision_model(robot)
        for label, phys in (("penalty", PhysicsConfig(method="penalty")), ("human", human_physics())):
            errs, jerks, t0 = [], [], time.perf_counter()
            for f in files:
                src = read_source(f, human_kind(f, None))
                res = retarget_features(src.features(), src.skeleton, robot.skeleton, method="optimize", physics=phys, geometry=[model])
                pos, _ = res.motion.forward_kinematics()
                eta = joint_map(robot.skeleton, src.skeleton)
                refs = list(np.flatnonzero(eta.any(0)))
                ti, rj = np.nonzero(eta)
                d = np.asarray(pos)[:, ti] - res.reference_points[:, [refs.index(j) for j in rj]]
                errs.append(float(np.linalg.norm(d, axis=-1).mean()))
                jerks.append(float(np.abs(np.diff(np.asarray(res.motion.q), 3, axis=0)).mean()))
            print(f"{name:8s} {label:8s} g-mpbpe {np.mean(errs) * 1000:6.1f} mm  jerk {np.mean(jerks):.4f}  "
                  f"{time.perf_counter() - t0:5.0f} s", flush=True)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder")
    ap.add_argument("--targets", nargs="+", default=["g1", "h1"])
    ap.add_argument("--every", type=int, default=1, help="every N-th clip (a subset first: the whole set is long)")
    ap.add_argument("--physics", choices=["default", "penalty", "constraints"], default="default",
                    help="the physical terms: the default command's for a human source, or a method named")
    ap.add_argument("--accuracy", action="store_true", help="instead: key-point error, jerk and time, penalty against human physics")
    ap.add_argument("--hz120", metavar="TMPDIR", help="also measure a 120 Hz copy of each BVH written there")
    a = ap.parse_args()
    torch.set_num_threads(1)
    files = sorted(p for p in Path(a.folder).iterdir() if p.suffix.lower() in (".bvh", ".npz", ".npy"))[:: a.every]
    from mer_models.retarget.clip import human_physics

    if a.accuracy:
        accuracy(files, a.targets)
        return
    physics = human_physics() if a.physics == "default" else PhysicsConfig(method=a.physics)
    print(f"physics: {physics.method}", flush=True)
    table(files, a.targets, f"{a.folder}", physics)
    if a.hz120:
        out = Path(a.hz120)
        out.mkdir(parents=True, exist_ok=True)
        table([write_120hz(f, out) for f in files if f.suffix.lower() == ".bvh"], a.targets, f"{a.folder} at 120 Hz", physics)


if __name__ == "__main__":
    main()
