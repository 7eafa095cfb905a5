"""Benchmark peer: GMR's BVH route next to mer's, on the same human motion capture clips, to G1.

`GMR <https://github.com/YanjieZe/GMR>`_ (General Motion Retargeting, Yanjie Ze et al., MIT
licence) retargets BVH motion capture to humanoids with mink (differential IK on MuJoCo): per frame,
each human body's position (scaled per body part about the hips) and orientation (times a fixed
per-body rotation offset from its IK config) is a ``mink.FrameTask`` target on a robot body, solved
in two stages (``ik_match_table1``, then ``ik_match_table2``), each frame warm-started from the last.
This tool runs it, unmodified, on the clips mer retargets (``mer retarget CLIP.bvh --target g1``) and
measures both retargeters with mer's metrics, on the same 30 Hz frames, in one run::

    .venv/bin/python tools/gmr_peer.py --gmr-python /path/to/gmr-venv/bin/python \\
        [--bvh-dir ../shared/data/bvh/bandai1] [--clips walk_normal_001 kick_normal_001] \\
        [--mer-methods optimize physics] [--human-height auto 1.75] [--calibration bye_normal_001] \\
        [--max-frames N] [--threads 1] [--json runs/gmr_peer.json]

**GMR is never part of mer**: not a dependency, not vendored, not imported by mer. Install it
yourself into a separate virtual environment from its public source, e.g.::

    python3 -m venv gmr-venv
    gmr-venv/bin/pip install mink mujoco "qpsolvers[daqp]" rich tqdm scipy numpy imageio loop_rate_limiters torch
    gmr-venv/bin/pip install --no-deps -e path/to/GMR      # its setup.py also wants smplx (git), redis, opencv: not
                                                           # needed for the BVH route
    # or set GMR_PYTHON=gmr-venv/bin/python instead of passing --gmr-python

This module runs itself in that interpreter (``--worker JOB.json``, numpy/scipy/GMR only; nothing of
mer is imported there) and reads the results back. Without a working GMR the tool says why and still
prints mer's rows.

What GMR is given (its BVH route is ``scripts/bvh_to_robot.py`` →
``general_motion_retargeting.utils.lafan1.load_lafan1_file`` → ``GeneralMotionRetargeting.retarget``
with ``ik_configs/bvh_to_g1.json``, written for LAFAN1's skeleton):

* **Reading**: GMR's own BVH reader and FK (``utils/lafan_vendor``: ``read_bvh``, ``quat_fk``), then
  the same conversion as ``load_lafan1_file`` (Y-up centimetres → Z-up metres). ``load_lafan1_file``
  itself cannot read these clips: it looks up LAFAN1's joint names (``LeftFoot``, ``LeftToe``...).
* **Names**: the clip's joints stand in for LAFAN1's in GMR's human frame dictionary (Bandai Namco's
  ``Hips, Chest, UpperLeg_L, LowerLeg_L, Foot_L/Toes_L, UpperArm_L, LowerArm_L, Hand_L`` for GMR's
  ``Hips, Spine2, LeftUpLeg, LeftLeg, LeftFootMod, LeftArm, LeftForeArm, LeftHand``; ``FootMod`` is
  the ankle's position with the toe's orientation, as in GMR).
* **Config**: GMR's ``bvh_to_g1.json`` as shipped (bodies, weights, scale table, two stages), except
  the rotation offsets: those are tied to LAFAN1's bone frames, and Bandai Namco's bone frames are
  others. They are calibrated on one pose where the human corresponds to G1's zero pose, by default
  the most neutral standing frame (mer's ``standing_frame``: legs straight, arms hanging, elbows
  bent about 20 degrees) of ``bye_normal_001`` (``--calibration CLIP[:FRAME]``; ``per-clip``: each
  clip's own standing frame, which goes wrong for clips that never stand neutrally, e.g. a kick
  with the arms in guard): ``offset = (D @ R_human)^-1 @ (Y @ R_robot_zero)``, ``Y`` the human's
  heading, ``D`` a turn into G1's zero pose: none for hips, chest and feet (standing ≈ G1 upright,
  feet flat); for each arm, the rotation that puts the upper arm and forearm along G1's (upper arm
  down, forearm forward: G1's zero pose has the elbows bent 90 degrees) with the elbow's axis (the
  normal of the two bones) on G1's elbow axis, the same for both bones so that GMR's upper-arm and
  forearm goals differ by a turn about G1's elbow joint (with a shortest rotation per bone instead,
  GMR missed its forearm goals by 50-60 degrees on the kick calibrated in its guard); for the legs (and an elbow bent under 10 degrees) the shortest rotation
  that turns the bone onto G1's; the hands turn with their forearms. The bones' frames are the same
  in every clip of the dataset (one rig: the knee's hinge is the bone frame's y in every clip), so
  one calibration serves all. The choice matters: on the default clips ``per-clip`` gave GMR a
  root-relative error of 48 mm instead of 58 mm (mer's reference is zeroed at the same frames) but
  self-penetration in 16 % of the frames instead of 4 %. The calibrated config is written to a temporary file and registered in
  GMR's ``IK_CONFIG_DICT`` at run time (GMR's code is not changed).
* **Height**: ``actual_human_height`` (``--human-height``, one GMR row per value): ``1.75``, the
  value ``load_lafan1_file`` passes whatever the clip (GMR's BVH route as shipped), and ``auto``,
  GMR's own estimate from the clip (head joint above the lower ankle + 0.2 m, computed and then
  discarded by ``load_lafan1_file``; about 1.45 m here). It sets all of GMR's scale factors
  (``0.9`` legs and root, ``0.75`` arms, times ``height / 1.8``).
* **Frame**: GMR scales the root's translation about the world origin, mer about the clip's start.
  So that both scale about the same point, GMR's input is moved rigidly into mer's frame (turned
  about z by mer's facing yaw, and shifted so the base starts at x = y = 0, exactly what mer's
  ``prepare_reference`` does); GMR's output is moved back with the same shift.

What is measured, on mer's G1 (``mer_data/robots/builtin/g1``): GMR's ``qpos`` (free joint, then
its hinge joints, matched to mer's joints by name) becomes a
:class:`~mer_models.export.writers.TargetMotion`, and every motion goes through
:func:`mer_models.retarget.clip.sequence_metrics` with G1's collision model:

* ``g-mpbpe``: key-point error to **mer's** scaled human reference [mm]. GMR scales the human its
  own way (fixed factors per body part, root translation included), so for GMR this measures how far
  it lands from mer's notion of the scaled human, not how well it tracks its own targets. Split into
  ``root`` (the base's error: mostly the scaling of the root's trajectory) and ``local`` (the other
  key points relative to the base: the pose). ``own``: each method's error to its own targets (mer:
  ``g-mpbpe``; GMR: its position-tracked robot bodies to its scaled human bodies, which includes
  the gaps its config leaves by design, e.g. G1's ``hip_yaw_link`` sits 25 cm below the hip joint it
  is pulled to);
* ``jerk`` [rad/frame^3] (the human reference's own is printed for scale), ``limits`` (share of
  frames outside a joint limit);
* the artifacts of :mod:`mer_models.retarget.artifacts`: frames with a foot below -1 cm and the
  deepest [cm], median contact-foot speed [cm/s] and the share of contact frames over 5 cm/s,
  self-penetration (> 1 mm, > 1 cm), frame pairs over a URDF joint speed limit, frames where the
  human has a foot down and no body of the robot is within 5 cm of the floor;
* frames/s of the retargeting alone (GMR: its per-frame ``retarget`` loop; mer: the
  ``retarget_features`` call), both after an untimed warm-up on 16 frames, mer on ``--threads``
  torch threads (default 1), GMR with OMP/BLAS limited to as many (its loop is single-threaded
  Python). With more threads than idle cores, other processes slow mer's threaded solver by up to
  30 times (seen on a shared 2-core machine at 2 threads), GMR's hardly: the load average at the
  start and end is printed.

Checks printed with the table, per clip: GMR's human input against mer's reading of the same file
(same frames, same world: 0.000 mm), GMR's MJCF kinematics against mer's URDF on GMR's own angles,
and GMR's orientation error to its own goals (a wrong calibration shows here first).

The Bandai Namco clips (``$MER_SHARED/data/bvh/bandai1``, CC BY-NC 4.0) are read in place: never
commit them or anything made from them (retargeted motions, this tool's JSON output).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

REPO = Path(__file__).resolve().parents[1]

#: Default clips (``dataset-1_<name>.bvh``): a walk, a walk backwards, a run, a dash, a kick, a sword slash, the dance.
CLIPS = ("walk_normal_001", "walk-back_proud_001", "run_happy_001", "dash_happy_001", "kick_normal_001",
         "slash_normal_001", "dance-short_normal_001")  # fmt: skip
#: The clip (and its most neutral standing frame: arms hanging, legs straight) GMR's rotation offsets are calibrated on.
CALIBRATION = "bye_normal_001"
#: GMR's robot name for mer's ``g1`` (29 dof, ``assets/unitree_g1/g1_mocap_29dof.xml``).
GMR_ROBOT = "unitree_g1"
#: The ``src_human`` key under which the calibrated config is registered in GMR's ``IK_CONFIG_DICT``.
GMR_SOURCE = "bvh_mer_peer"
#: GMR's BVH loader (``utils/lafan1.py``): file axes (Y up) → world (Z up); positions are also / 100.
GMR_Y_TO_Z = ((1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0))
#: ``actual_human_height`` GMR's BVH loader passes [m].
GMR_HUMAN_HEIGHT = 1.75
#: GMR human body (LAFAN1 name, as in ``bvh_to_g1.json``) → the Bandai Namco joint that stands in for it.
BANDAI_BODIES = {
    "Hips": "Hips", "Spine2": "Chest",
    "LeftUpLeg": "UpperLeg_L", "LeftLeg": "LowerLeg_L", "LeftArm": "UpperArm_L", "LeftForeArm": "LowerArm_L", "LeftHand": "Hand_L",
    "RightUpLeg": "UpperLeg_R", "RightLeg": "LowerLeg_R", "RightArm": "UpperArm_R", "RightForeArm": "LowerArm_R", "RightHand": "Hand_R",
}  # fmt: skip
#: GMR's ``FootMod`` bodies: (joint giving the position, joint giving the orientation).
BANDAI_FEET = {"LeftFootMod": ("Foot_L", "Toes_L"), "RightFootMod": ("Foot_R", "Toes_R")}
#: Calibrated bones: GMR human body → ((human joint, child joint), (G1 body, G1 body further down the limb)).
CAL_BONES = {
    "LeftUpLeg": (("UpperLeg_L", "LowerLeg_L"), ("left_hip_roll_link", "left_knee_link")),
    "LeftLeg": (("LowerLeg_L", "Foot_L"), ("left_knee_link", "left_ankle_roll_link")),
    "LeftArm": (("UpperArm_L", "LowerArm_L"), ("left_shoulder_roll_link", "left_elbow_link")),
    "LeftForeArm": (("LowerArm_L", "Hand_L"), ("left_elbow_link", "left_wrist_yaw_link")),
    "RightUpLeg": (("UpperLeg_R", "LowerLeg_R"), ("right_hip_roll_link", "right_knee_link")),
    "RightLeg": (("LowerLeg_R", "Foot_R"), ("right_knee_link", "right_ankle_roll_link")),
    "RightArm": (("UpperArm_R", "LowerArm_R"), ("right_shoulder_roll_link", "right_elbow_link")),
    "RightForeArm": (("LowerArm_R", "Hand_R"), ("right_elbow_link", "right_wrist_yaw_link")),
}
#: Calibrated hinges: the two bones of an elbow (GMR human bodies) share the elbow's axis; the
#: other bones of ``CAL_BONES`` (and these, where the elbow is nearly straight) turn the shortest way.
CAL_HINGES = (("LeftArm", "LeftForeArm"), ("RightArm", "RightForeArm"))
#: Least elbow bend [rad] at which its axis is taken from the calibration frame.
MIN_BEND = math.radians(10.0)
#: Bodies that turn with another's calibration (the hand has no bone of its own in these files).
CAL_FOLLOW = {"LeftHand": "LeftForeArm", "RightHand": "RightForeArm"}
#: (left, right) hip joints: the human's heading at the calibration frame (left points along +y when facing +x).
HEADING_JOINTS = ("UpperLeg_L", "UpperLeg_R")
FPS = 30.0
INSTALL_HINT = ("install GMR (github.com/YanjieZe/GMR, MIT) into its own virtual environment and pass its interpreter "
                "with --gmr-python or GMR_PYTHON (module docstring: tools/gmr_peer.py)")  # fmt: skip


# ---- rotations (numpy only: used by both interpreters) -----------------------------------------


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions wxyz → (..., 3, 3) rotation matrices."""
    q = np.asarray(q, np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)  # fmt: skip


def rotmat_to_quat(m: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix → (4,) unit quaternion wxyz (w >= 0)."""
    m = np.asarray(m, np.float64)
    t = np.trace(m)
    if t > 0:
        s = 2.0 * math.sqrt(1.0 + t)
        q = np.array([0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s])
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + m[i, i] - m[j, j] - m[k, k], 1e-300))
        q = np.empty(4)
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def shortest_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation that turns direction ``a`` onto direction ``b``."""
    a = np.asarray(a, np.float64) / np.linalg.norm(a)
    b = np.asarray(b, np.float64) / np.linalg.norm(b)
    axis = np.cross(a, b)
    s, c = float(np.linalg.norm(axis)), float(np.dot(a, b))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(a, np.eye(3)[int(np.argmin(np.abs(a)))])  # opposite: half a turn about any perpendicular
        perp /= np.linalg.norm(perp)
        return 2.0 * np.outer(perp, perp) - np.eye(3)
    k = axis / s
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    angle = math.atan2(s, c)
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K


def frame_rotation(u1: np.ndarray, v1: np.ndarray, u2: np.ndarray, v2: np.ndarray) -> np.ndarray:
    """(3, 3) the rotation that turns direction ``u1`` onto ``u2`` and the plane of ``u1``, ``v1`` onto
    that of ``u2``, ``v2`` (``v1`` onto ``v2`` where both are perpendicular to their ``u``)."""

    def frame(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        a = np.asarray(u, np.float64) / np.linalg.norm(u)
        b = np.asarray(v, np.float64) - np.dot(v, a) * a
        b /= np.linalg.norm(b)
        return np.stack([a, b, np.cross(a, b)], axis=1)

    return frame(u2, v2) @ frame(u1, v1).T


def rot_z(angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` [rad] about +z."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def calibrated_offsets(
    pos: dict[str, np.ndarray],
    rot: dict[str, np.ndarray],
    robot_pos: dict[str, np.ndarray],
    robot_rot: dict[str, np.ndarray],
    table: dict[str, list],
) -> dict[str, list[float]]:
    """GMR rotation offsets (wxyz, per GMR human body) that map the human at a standing frame to G1's zero pose.

    Args:
        pos, rot: the human at the calibration frame: Bandai Namco joint → world position (3,) [m] and
            orientation (3, 3) (z up).
        robot_pos, robot_rot: G1 at its zero pose (base at the origin, identity): body → world
            position (3,) and orientation (3, 3).
        table: a GMR ``ik_match_table`` (robot body → [human body, pos weight, rot weight, pos offset, rot offset]).

    Returns:
        GMR human body → rotation offset wxyz: ``(D @ R_human)^-1 @ (Y @ R_robot)`` (module docstring).
    """
    left = pos[HEADING_JOINTS[0]] - pos[HEADING_JOINTS[1]]
    heading = rot_z(math.atan2(left[1], left[0]) - math.pi / 2)  # turns +y (G1's left) onto the human's left

    def bone(body: str) -> tuple[np.ndarray, np.ndarray]:
        (hj, hc), (rj, rc) = CAL_BONES[body]
        return pos[hc] - pos[hj], heading @ (robot_pos[rc] - robot_pos[rj])

    turns: dict[str, np.ndarray] = {}
    for upper, lower in CAL_HINGES:  # an elbow: both bones keep the elbow's axis (its hinge) in common
        (hu, ru), (hl, rl) = bone(upper), bone(lower)
        n_h, n_r = np.cross(hu, hl), np.cross(ru, rl)
        bend = math.atan2(np.linalg.norm(n_h), float(np.dot(hu, hl)))
        if bend >= MIN_BEND and np.linalg.norm(n_r) > 1e-9:
            turns[upper] = frame_rotation(hu, n_h, ru, n_r)
            turns[lower] = frame_rotation(hl, n_h, rl, n_r)

    def turn(body: str) -> np.ndarray:
        if body in turns:
            return turns[body]
        if body not in CAL_BONES:
            return np.eye(3)
        return shortest_rotation(*bone(body))

    out = {}
    for link, entry in table.items():
        body = entry[0]
        if body in BANDAI_FEET:
            joint = BANDAI_FEET[body][1]
        elif body in BANDAI_BODIES:
            joint = BANDAI_BODIES[body]
        else:
            raise ValueError(f"GMR's config names a human body {body!r} this tool cannot map to a Bandai Namco joint")
        D = turn(CAL_FOLLOW.get(body, body))
        off = (D @ rot[joint]).T @ heading @ robot_rot[link]
        out[body] = [float(v) for v in rotmat_to_quat(off)]
    return out


def auto_height(pos: dict[str, np.ndarray]) -> float:
    """GMR's own estimate of the actor's height [m] from a (standing) frame: the head joint's height above
    the lower ankle plus 0.2 m (``load_lafan1_file`` computes this, the + 0.2 in a commented-out line,
    then passes 1.75 instead)."""
    return float(pos["Head"][2] - min(pos["Foot_L"][2], pos["Foot_R"][2]) + 0.2)


# ---- worker: runs in GMR's interpreter (numpy, scipy, mujoco, GMR; nothing of mer) ------------


def _gmr_human(path: str, world: np.ndarray, shift: np.ndarray) -> tuple[list[str], np.ndarray, np.ndarray]:
    """GMR's reading of a BVH (its ``read_bvh`` + ``quat_fk`` + ``load_lafan1_file``'s axes and units),
    moved rigidly into mer's frame: names, (F, N, 3) positions [m], (F, N, 4) orientations wxyz."""
    from general_motion_retargeting.utils.lafan_vendor import utils as lafan_utils
    from general_motion_retargeting.utils.lafan_vendor.extract import read_bvh

    data = read_bvh(path)
    grot, gpos = lafan_utils.quat_fk(data.quats, data.pos, data.parents)
    to_z = np.asarray(GMR_Y_TO_Z)
    q_to_z = rotmat_to_quat(to_z)
    pos = gpos @ to_z.T / 100.0  # as load_lafan1_file: cm -> m
    quat = lafan_utils.quat_mul(q_to_z, grot)
    pos = pos @ world.T - shift  # into mer's frame (a turn about z and a shift: module docstring)
    quat = lafan_utils.quat_mul(rotmat_to_quat(world), quat)
    return list(data.bones), pos, quat


def _frame_dict(index: dict[str, int], pos: np.ndarray, quat: np.ndarray, t: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """GMR's per-frame human data: GMR body name → (position, quaternion wxyz)."""
    out = {g: (pos[t, index[b]].copy(), quat[t, index[b]].copy()) for g, b in BANDAI_BODIES.items()}
    for g, (p, r) in BANDAI_FEET.items():
        out[g] = (pos[t, index[p]].copy(), quat[t, index[r]].copy())
    return out


def _worker(job_path: str) -> int:
    """Run GMR on every clip of a job file (see :func:`run_gmr`); one ``.npz`` per clip."""
    job = json.loads(Path(job_path).read_text())
    if job.get("threads"):
        os.environ.setdefault("OMP_NUM_THREADS", str(job["threads"]))
    import mujoco
    from general_motion_retargeting import GeneralMotionRetargeting
    from general_motion_retargeting.params import IK_CONFIG_DICT, ROBOT_XML_DICT

    robot = job["robot"]
    base_cfg = json.loads(Path(IK_CONFIG_DICT["bvh"][robot]).read_text())
    model = mujoco.MjModel.from_xml_path(str(ROBOT_XML_DICT[robot]))
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)  # qpos0: pelvis free joint at its default height, identity
    bodies = [model.body(i).name for i in range(model.nbody)]
    robot_pos = {b: data.xpos[i] - data.xpos[1] for i, b in enumerate(bodies)}
    robot_rot = {b: data.xmat[i].reshape(3, 3).copy() for i, b in enumerate(bodies)}
    hinges = [j for j in range(model.njnt) if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_FREE]
    joint_names = [model.joint(j).name for j in hinges]
    joint_body = model.jnt_bodyid[hinges]
    tmp = Path(job["tmp"])

    def offsets_at(path: str, world: np.ndarray, frame: int) -> dict[str, list[float]]:
        names, pos, quat = _gmr_human(path, world, np.zeros(3))
        return calibrated_offsets({n: pos[frame, i] for i, n in enumerate(names)},
                                  {n: quat_to_rotmat(quat[frame, i]) for i, n in enumerate(names)},
                                  robot_pos, robot_rot, base_cfg["ik_match_table1"])  # fmt: skip

    cal = job.get("calibration")
    common = offsets_at(cal["path"], np.asarray(cal["world"]), int(cal["frame"])) if cal else None
    warm = True  # the first GMR instance runs 16 frames untimed first (first-call costs out of the timing)
    for clip in job["clips"]:
        try:
            names, pos, quat = _gmr_human(clip["path"], np.asarray(clip["world"]), np.asarray(clip["shift"]))
            index = {n: i for i, n in enumerate(names)}
            s = int(clip["standing_frame"])
            cfg = json.loads(json.dumps(base_cfg))
            offsets = common or offsets_at(clip["path"], np.asarray(clip["world"]), s)
            for table in ("ik_match_table1", "ik_match_table2"):
                for entry in cfg[table].values():
                    entry[4] = offsets[entry[0]]
            cfg_path = tmp / f"{clip['name']}.bvh_to_g1.json"
            cfg_path.write_text(json.dumps(cfg, indent=1))
            IK_CONFIG_DICT[GMR_SOURCE] = {robot: cfg_path}  # GMR reads its config from this dict
            n = min(int(clip["frames"]), len(pos))
            tracked = [(b, e[0]) for b, e in cfg["ik_match_table2"].items() if e[1] > 0]
            tracked_ids = [model.body(b).id for b, _ in tracked]
            turned = [(b, e[0]) for b, e in cfg["ik_match_table1"].items() if e[2] > 0]
            turned_ids = [model.body(b).id for b, _ in turned]
        except Exception as exc:  # noqa: BLE001 - reported per clip to the parent
            for v in range(len(job["heights"])):
                (tmp / f"{clip['name']}.{v}.error").write_text(f"{type(exc).__name__}: {exc}")
            print(f"gmr {clip['name']}: failed: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
            continue
        for v, height in enumerate(job["heights"]):
            try:
                if height == "auto":
                    height = auto_height({n: pos[s, i] for n, i in index.items()})
                gmr = GeneralMotionRetargeting(src_human=GMR_SOURCE, tgt_robot=robot, actual_human_height=float(height))
                if warm:
                    spare = GeneralMotionRetargeting(src_human=GMR_SOURCE, tgt_robot=robot, actual_human_height=float(height))
                    for t in range(min(16, n)):
                        spare.retarget(_frame_dict(index, pos, quat, t))
                    warm = False
                frames = [_frame_dict(index, pos, quat, t) for t in range(n)]  # loading is outside GMR's loop too
                qpos = np.empty((n, model.nq))
                targets = np.empty((n, len(tracked), 3))
                goals = np.empty((n, len(turned), 4))
                t0 = time.perf_counter()
                for t in range(n):
                    qpos[t] = gmr.retarget(frames[t])
                    targets[t] = [gmr.scaled_human_data[h][0] for _, h in tracked]
                    goals[t] = [gmr.scaled_human_data[h][1] for _, h in turned]
                seconds = time.perf_counter() - t0
                achieved = np.empty_like(targets)
                turned_rot = np.empty((n, len(turned), 3, 3))
                joint_xpos = np.empty((n, len(hinges), 3))
                for t in range(n):
                    data.qpos[:] = qpos[t]
                    mujoco.mj_kinematics(model, data)
                    achieved[t] = data.xpos[tracked_ids]
                    turned_rot[t] = data.xmat[turned_ids].reshape(-1, 3, 3)
                    joint_xpos[t] = data.xpos[joint_body]
                own = np.linalg.norm(achieved - targets, axis=-1)
                cos = (np.einsum("fkij,fkij->fk", quat_to_rotmat(goals), turned_rot) - 1.0) / 2.0
                own_rot = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
                np.savez(
                    tmp / f"{clip['name']}.{v}.npz", qpos=qpos, seconds=seconds, joint_names=np.array(joint_names),
                    hips=pos[:n, index["Hips"]], own_err=own.mean(), own_err_bodies=own.mean(0),
                    tracked=np.array([h for _, h in tracked]), own_rot=own_rot.mean(), own_rot_bodies=own_rot.mean(0),
                    turned=np.array([h for _, h in turned]), joint_xpos=joint_xpos, offsets=json.dumps(offsets),
                    height=float(height),
                )  # fmt: skip
                print(f"gmr {clip['name']} (height {float(height):.2f} m): {n} frames in {seconds:.2f} s "
                      f"({n / seconds:.0f} frames/s)", file=sys.stderr, flush=True)  # fmt: skip
            except Exception as exc:  # noqa: BLE001 - reported per clip to the parent
                (tmp / f"{clip['name']}.{v}.error").write_text(f"{type(exc).__name__}: {exc}")
                print(f"gmr {clip['name']}: failed: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
    return 0


# ---- parent: mer's side ------------------------------------------------------------------------


class GmrUnavailable(RuntimeError):
    """GMR cannot run here; the message says why and what to do."""


def gmr_python(given: str | None = None) -> str:
    """The interpreter that has GMR: ``given``, else ``$GMR_PYTHON``, else this one."""
    return given or os.environ.get("GMR_PYTHON") or sys.executable


def check_gmr(python: str, timeout: float = 300.0) -> str:
    """Check that ``python`` can import GMR and its solver stack; returns a one-line description.

    Raises:
        GmrUnavailable: with the reason (missing interpreter, import error, missing G1 model).
    """
    probe = ("import general_motion_retargeting as g, mink, mujoco, daqp, pathlib; "
             "x = g.ROBOT_XML_DICT['unitree_g1']; c = g.IK_CONFIG_DICT['bvh']['unitree_g1']; "
             "assert pathlib.Path(x).is_file() and pathlib.Path(c).is_file(), (x, c); "
             "mujoco.MjModel.from_xml_path(str(x)); "
             "print(pathlib.Path(g.__file__).parent.parent, 'mujoco', mujoco.__version__)")  # fmt: skip
    try:
        out = subprocess.run([python, "-c", probe], capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise GmrUnavailable(f"cannot run {python}: {exc}; {INSTALL_HINT}") from None
    if out.returncode != 0:
        last = (out.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise GmrUnavailable(f"{python} cannot run GMR: {last}; {INSTALL_HINT}")
    return out.stdout.strip()


def clip_path(bvh_dir: Path, name: str) -> Path:
    """``name`` as a path (``x.bvh``), else ``<bvh_dir>/dataset-1_<name>.bvh``, else ``<bvh_dir>/<name>.bvh``."""
    if name.endswith(".bvh"):
        return Path(name)
    for cand in (bvh_dir / f"dataset-1_{name}.bvh", bvh_dir / f"{name}.bvh"):
        if cand.is_file():
            return cand
    raise SystemExit(f"no clip {name!r} in {bvh_dir} (set MER_SHARED or pass --bvh-dir)")


def prepare_clip(path: Path, max_frames: int | None = None) -> dict[str, Any]:
    """mer's reading of one clip and what GMR's run needs to see the same frames in the same world.

    Returns:
        ``src`` (:class:`~mer_data.motion.sources.SourceMotion`), ``feats`` (F, J, 9), ``shift`` (3,),
        ``world`` (3, 3) GMR's world → mer's (a turn about z), ``standing_frame``, ``hips`` (F, 3)
        mer's hips positions [m] (for the input check), ``frames``.
    """
    from mer_data.motion.bvh import read_bvh
    from mer_data.motion.human import standing_frame
    from mer_data.motion.sources import SOURCE_FPS, read_source

    clip = read_bvh(path)
    if clip.units != "cm" or clip.up != "y":
        raise ValueError(f"{path.name}: GMR's BVH loader assumes Y-up centimetres; mer reads {clip.up}-up {clip.units}")
    if clip.fps != SOURCE_FPS:
        raise ValueError(f"{path.name}: {clip.fps:g} Hz; GMR retargets the file's frames and mer 30 Hz ones: give a 30 Hz clip")
    src = read_source(path, "bvh")
    feats = src.features()
    n = len(feats) if max_frames is None else min(len(feats), max_frames)
    world = clip.to_world @ np.asarray(GMR_Y_TO_Z).T
    if not np.allclose(world[2], [0.0, 0.0, 1.0], atol=1e-9):  # both map the file's +y to +z: a turn about z
        raise ValueError(f"{path.name}: GMR's and mer's worlds differ by more than a turn about z")
    return {"name": path.stem.removeprefix("dataset-1_"), "path": path, "src": src, "feats": feats[:n], "frames": n,
            "shift": np.array([feats[0, 0, 3], feats[0, 0, 4], 0.0]), "world": world, "standing_frame": standing_frame(clip),
            "hips": clip.positions(slice(0, n))[:, clip.index("Hips")]}  # fmt: skip


def calibration_frame(path: Path, frame: int | None = None) -> dict[str, Any]:
    """The pose GMR's rotation offsets are calibrated on: ``path``, ``world`` (as :func:`prepare_clip`)
    and ``frame`` (0-based; default mer's ``standing_frame`` of the clip)."""
    from mer_data.motion.bvh import read_bvh
    from mer_data.motion.human import standing_frame

    clip = read_bvh(path)
    f = standing_frame(clip) if frame is None else int(frame)
    if not 0 <= f < clip.num_frames:
        raise SystemExit(f"calibration frame {f} is not a frame of {path.name} ({clip.num_frames} frames)")
    return {"path": str(path), "world": (clip.to_world @ np.asarray(GMR_Y_TO_Z).T).tolist(), "frame": f}


def run_gmr(python: str, clips: Sequence[dict[str, Any]], *, heights: Sequence[float | str] = ("auto",),
            calibration: dict[str, Any] | None = None, threads: int = 1, timeout: float = 3600.0) -> list[dict[str, dict[str, Any]]]:  # fmt: skip
    """Run GMR on ``clips`` (from :func:`prepare_clip`) in its interpreter, once per ``actual_human_height``
    of ``heights`` (metres, or ``"auto"``: :func:`auto_height` at the clip's standing frame), with the
    rotation offsets calibrated on ``calibration`` (:func:`calibration_frame`; None: each clip at its
    own standing frame).

    Returns:
        One dict per height: clip name → its outputs (``qpos`` (F, 7 + n), ``joint_names``, ``seconds``,
        ``hips``, ``own_err`` [m] / ``own_err_bodies`` (position tracking of its own targets, bodies
        ``tracked``), ``own_rot`` [deg] / ``own_rot_bodies`` (orientation tracking, bodies ``turned``),
        ``joint_xpos``, ``offsets``, ``height``)
        or ``{"error": message}``.

    Raises:
        GmrUnavailable: the worker did not run.
    """
    with tempfile.TemporaryDirectory(prefix="gmr_peer_") as tmp:
        job = {"robot": GMR_ROBOT, "heights": list(heights), "calibration": calibration, "tmp": tmp, "threads": threads, "clips": [
            {"name": c["name"], "path": str(c["path"]), "world": c["world"].tolist(), "shift": c["shift"].tolist(),
             "standing_frame": c["standing_frame"], "frames": c["frames"]} for c in clips]}  # fmt: skip
        (Path(tmp) / "job.json").write_text(json.dumps(job))
        env = {
            **os.environ,
            "OMP_NUM_THREADS": str(threads),
            "OPENBLAS_NUM_THREADS": str(threads),
            "MKL_NUM_THREADS": str(threads),
        }
        try:
            proc = subprocess.run([python, str(Path(__file__).resolve()), "--worker", str(Path(tmp) / "job.json")],
                                  env=env, timeout=timeout, cwd=tmp)  # fmt: skip
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise GmrUnavailable(f"GMR's run failed: {exc}") from None
        if proc.returncode != 0:
            raise GmrUnavailable(f"GMR's run exited with status {proc.returncode} (its messages are above)")
        outs: list[dict[str, dict[str, Any]]] = []
        for v in range(len(heights)):
            out: dict[str, dict[str, Any]] = {}
            for c in clips:
                npz, err = Path(tmp) / f"{c['name']}.{v}.npz", Path(tmp) / f"{c['name']}.{v}.error"
                if npz.is_file():
                    with np.load(npz) as z:
                        out[c["name"]] = {k: z[k] for k in z.files}
                    out[c["name"]]["offsets"] = json.loads(str(out[c["name"]]["offsets"]))
                else:
                    out[c["name"]] = {"error": err.read_text() if err.is_file() else "no output"}
            outs.append(out)
        return outs


def gmr_motion(qpos: np.ndarray, joint_names: Sequence[str], skeleton: Any, shift: np.ndarray, fps: float = FPS) -> Any:
    """GMR's ``qpos`` (F, 7 + n) (base position, base quaternion wxyz, hinge angles in ``joint_names``
    order), in mer's prepared frame, as a world-frame :class:`~mer_models.export.writers.TargetMotion` of
    ``skeleton`` (node angles by joint name; ``shift`` added back to the base position).

    Raises:
        ValueError: a degree of freedom of ``skeleton`` that GMR's model lacks.
    """
    from mer_models.export.writers import TargetMotion

    qpos = np.asarray(qpos, np.float64)
    col = {str(n): 7 + i for i, n in enumerate(joint_names)}
    q = np.zeros((len(qpos), skeleton.num_nodes))
    for j in np.flatnonzero(skeleton.dof_mask):
        name = skeleton.node_names[j]
        if name not in col:
            raise ValueError(f"GMR's model has no joint {name!r} of {skeleton.name}")
        q[:, j] = qpos[:, col[name]]
    base_pos = qpos[:, 0:3] + np.asarray(shift, np.float64)
    return TargetMotion(skeleton, fps, q, base_pos, quat_to_rotmat(qpos[:, 3:7]))


def keypoint_split(motion: Any, prepared: tuple, source: Any) -> dict[str, float]:
    """Key-point error of ``motion`` to mer's scaled reference, split into the base and the rest.

    Args:
        motion: a world-frame :class:`~mer_models.export.writers.TargetMotion`.
        prepared: :func:`~mer_models.retarget.long_horizon.prepare_reference` of the reference for
            this target (``RetargetResult.prepared``); source: the reference skeleton.

    Returns:
        ``kp_all`` [m] the mean over frames and key-point pairs (``g_mpbpe``'s definition),
        ``kp_root`` the base's alone (where the root was put: scaling of the trajectory),
        ``kp_local`` the others relative to the base (``|(p - p_base) - (p* - p*_base)|``: the pose).
    """
    from mer_data.kinematics.jointmap import joint_map

    _, scaled, shift, _ = prepared
    eta = joint_map(motion.skeleton, source)
    tgt = np.flatnonzero(eta.any(1))
    ref = eta[tgt].argmax(1)
    pos, _ = motion.forward_kinematics()
    p, g = pos[:, tgt], scaled[:, ref] + shift
    b = int(np.flatnonzero(tgt == 0)[0])  # the floating bases are a pair
    rest = np.arange(len(tgt)) != b
    local = (p[:, rest] - p[:, b : b + 1]) - (g[:, rest] - g[:, b : b + 1])
    return {"kp_all": float(np.linalg.norm(p - g, axis=-1).mean()), "kp_root": float(np.linalg.norm(p[:, b] - g[:, b], axis=-1).mean()),
            "kp_local": float(np.linalg.norm(local, axis=-1).mean())}  # fmt: skip


def _mean(rows: Sequence[dict[str, Any]], key: str) -> float:
    v = np.array([r[key] for r in rows if r.get(key) is not None], np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if len(v) else float("nan")


def summarize(rows: Sequence[dict[str, Any]]) -> dict[str, float]:
    """Clip means of the per-clip metrics (frames/s: total frames / total seconds; deepest: the max)."""
    keys = ("g_mpbpe", "kp_root", "kp_local", "jerk_frame", "ref_jerk_frame", "limit_violation", "floor_frames", "skate_median", "skate_share",
            "selfpen_frames", "selfpen_1cm_frames", "speed_frames", "floating_frames", "own_err")  # fmt: skip
    out = {k: _mean(rows, k) for k in keys}
    out["floor_depth_max"] = max((r["floor_depth_max"] for r in rows), default=float("nan"))
    out["frames"] = float(sum(r["frames"] for r in rows))
    out["frames_per_s"] = out["frames"] / max(sum(r["seconds"] for r in rows), 1e-12)
    return out


def _fmt(v: float, scale: float = 1.0, spec: str = ".3f") -> str:
    return f"{v * scale:{spec}}" if v is not None and np.isfinite(v) else "-"


def print_table(
    summary: dict[str, dict[str, float]], per_clip: dict[str, dict[str, dict[str, Any]]], clips: Sequence[str]
) -> None:
    """The comparison table (all clips) and the per-clip key-point error."""
    print(f"\nG1, {len(clips)} Bandai Namco clips ({', '.join(clips)}); clip means. g-mpbpe: key-point error to mer's "
          "scaled human [mm], split into root (the base's) and local (the others relative to the base); own: to the "
          "method's own targets [mm]; jerk [rad/frame^3]; shares of frames; deepest [cm]; skate: median contact-foot "
          "speed [cm/s]")  # fmt: skip
    head = (f"{'method':12s} {'frames':>6s} {'g-mpbpe':>8s} {'root':>6s} {'local':>6s} {'own':>6s} {'jerk':>7s} {'limits':>7s} {'foot<-1cm':>9s} "
            f"{'deepest':>7s} {'skate':>6s} {'skate>5':>7s} {'selfpen':>7s} {'pen>1cm':>7s} {'>v.lim':>7s} {'float':>6s} {'fr/s':>6s}")  # fmt: skip
    print(head)
    for method, r in summary.items():
        print(f"{method:12s} {r['frames']:6.0f} {_fmt(r['g_mpbpe'], 1e3, '.1f'):>8s} {_fmt(r['kp_root'], 1e3, '.1f'):>6s} "
              f"{_fmt(r['kp_local'], 1e3, '.1f'):>6s} {_fmt(r['own_err'], 1e3, '.1f'):>6s} "
              f"{_fmt(r['jerk_frame'], 1, '.4f'):>7s} {_fmt(r['limit_violation']):>7s} {_fmt(r['floor_frames']):>9s} "
              f"{_fmt(r['floor_depth_max'], 100, '.1f'):>7s} {_fmt(r['skate_median'], 100, '.1f'):>6s} "
              f"{_fmt(r['skate_share']):>7s} {_fmt(r['selfpen_frames']):>7s} {_fmt(r['selfpen_1cm_frames']):>7s} "
              f"{_fmt(r['speed_frames']):>7s} {_fmt(r['floating_frames']):>6s} {_fmt(r['frames_per_s'], 1, '.0f'):>6s}")  # fmt: skip
    ref = next(iter(summary.values()), {}).get("ref_jerk_frame", float("nan"))
    print(f"(the human reference's own jerk: {_fmt(ref, 1, '.4f')} rad/frame^3)")
    print("\ng-mpbpe per clip [mm] (local: root-relative)")
    print(f"{'method':12s} " + " ".join(f"{c[:16]:>16s}" for c in clips))
    for method, by_clip in per_clip.items():
        cells = []
        for c in clips:
            r = by_clip.get(c, {})
            cells.append(
                f"{_fmt(r.get('g_mpbpe', float('nan')), 1e3, '.0f')} ({_fmt(r.get('kp_local', float('nan')), 1e3, '.0f')})"
            )
        print(f"{method:12s} " + " ".join(f"{x:>16s}" for x in cells))


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (module docstring)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--worker"]:
        return _worker(argv[1])
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--bvh-dir", type=Path, default=None, help="folder of the clips (default $MER_SHARED/data/bvh/bandai1)")
    p.add_argument("--clips", nargs="+", default=list(CLIPS), help="clip names (dataset-1_<name>.bvh) or .bvh paths")
    p.add_argument("--gmr-python", default=None, help="the interpreter GMR is installed in (default $GMR_PYTHON, else this one)")
    p.add_argument(
        "--mer-methods",
        nargs="*",
        default=["optimize", "physics"],
        choices=["optimize", "physics"],
        help="mer's optimiser without its physical terms (--no-physics) and with them (mer retarget's default)",
    )
    p.add_argument("--human-height", nargs="+", default=["auto", str(GMR_HUMAN_HEIGHT)],
                   help="GMR's actual_human_height [m], one GMR row each: a number (its BVH loader passes 1.75), or auto "
                        "(GMR's own estimate from the clip, auto_height)")  # fmt: skip
    p.add_argument("--calibration", default=CALIBRATION,
                   help="where GMR's rotation offsets are calibrated: CLIP or CLIP:FRAME (0-based; default frame: the clip's "
                        "most neutral standing frame), or per-clip (each clip's own standing frame)")  # fmt: skip
    p.add_argument("--max-frames", type=int, default=None, help="only the first N frames of each clip")
    p.add_argument(
        "--threads", type=int, default=1, help="torch threads for mer, OMP/BLAS threads for GMR (1: both single-threaded)"
    )
    p.add_argument("--json", type=Path, help="also write every figure here (made from CC BY-NC data: never commit it)")
    args = p.parse_args(argv)

    import torch

    sys.path.insert(0, str(REPO))
    from mer_data.robots.collision import collision_model
    from mer_data.robots.registry import load_robot
    from mer_models.retarget.clip import retarget_features, sequence_metrics
    from mer_models.retarget.long_horizon import prepare_reference
    from mer_models.solver.physics import PhysicsConfig

    torch.set_num_threads(args.threads)
    load0 = os.getloadavg()[0]
    bvh_dir = args.bvh_dir or Path(os.environ.get("MER_SHARED", REPO.parent / "shared")) / "data" / "bvh" / "bandai1"
    clips = [prepare_clip(clip_path(bvh_dir, c), args.max_frames) for c in args.clips]
    names = [c["name"] for c in clips]
    robot = load_robot("g1")
    geom = collision_model(robot)
    skel = robot.skeleton

    python = gmr_python(args.gmr_python)
    heights: list[float | str] = [h if h == "auto" else float(h) for h in args.human_height]
    gmr_outs: list[dict[str, dict[str, Any]]] = []
    try:
        print(f"GMR: {check_gmr(python)} ({python})", file=sys.stderr)
        cal = None
        if args.calibration != "per-clip":
            name, _, frame = args.calibration.partition(":")
            cal = calibration_frame(clip_path(bvh_dir, name), int(frame) if frame else None)
            print(f"GMR's rotation offsets calibrated on {Path(cal['path']).name}, frame {cal['frame']}", file=sys.stderr)
        gmr_outs = run_gmr(python, clips, heights=heights, calibration=cal, threads=args.threads)
    except GmrUnavailable as exc:
        print(f"GMR cannot run here, so only mer's rows are printed: {exc}", file=sys.stderr)

    per_clip: dict[str, dict[str, dict[str, Any]]] = {}
    checks: list[str] = []
    prepared: dict[str, tuple] = {}
    for method in args.mer_methods:
        label = f"mer {method}"
        physics = PhysicsConfig() if method == "physics" else None
        warm = clips[0]["feats"][:16]  # an untimed warm-up call (first-call costs out of the timing)
        retarget_features(warm, clips[0]["src"].skeleton, skel, method="optimize", fps=FPS, physics=physics)
        for c in clips:
            t0 = time.perf_counter()
            res = retarget_features(c["feats"], c["src"].skeleton, skel, method="optimize", fps=FPS, physics=physics)
            sec = time.perf_counter() - t0
            prepared[c["name"]] = res.prepared
            m = sequence_metrics(c["feats"], c["src"].skeleton, res.motion, prepared=res.prepared, geometry=geom)
            m.update(keypoint_split(res.motion, res.prepared, c["src"].skeleton))
            per_clip.setdefault(label, {})[c["name"]] = {**m, "frames": c["frames"], "seconds": sec, "own_err": m["g_mpbpe"]}
            print(
                f"{label} {c['name']}: {c['frames']} frames in {sec:.2f} s, g-mpbpe {1e3 * m['g_mpbpe']:.1f} mm", file=sys.stderr
            )
    gmr_labels = []
    for h, gmr_out in zip(heights, gmr_outs):
        label = f"GMR h={h}"
        gmr_labels.append(label)
        for c in clips:
            g = gmr_out.get(c["name"], {"error": "no output"})
            if "error" in g:
                checks.append(f"{label} failed on {c['name']}: {g['error']}")
                continue
            motion = gmr_motion(g["qpos"], [str(n) for n in g["joint_names"]], skel, c["shift"])
            if c["name"] not in prepared:
                prepared[c["name"]] = prepare_reference(c["feats"], c["src"].skeleton, skel)
            m = sequence_metrics(c["feats"], c["src"].skeleton, motion, prepared=prepared[c["name"]], geometry=geom)
            m.update(keypoint_split(motion, prepared[c["name"]], c["src"].skeleton))
            per_clip.setdefault(label, {})[c["name"]] = {**m, "frames": c["frames"], "seconds": float(g["seconds"]),
                                                         "own_err": float(g["own_err"]), "height": float(g["height"]),
                                                         "own_err_bodies": dict(zip(map(str, g["tracked"]), map(float, g["own_err_bodies"]))),
                                                         "own_rot": float(g["own_rot"]),
                                                         "own_rot_bodies": dict(zip(map(str, g["turned"]), map(float, g["own_rot_bodies"])))}  # fmt: skip
            # checks: same human input; GMR's MJCF kinematics against mer's URDF on GMR's angles
            d_in = float(np.abs(g["hips"] + c["shift"] - c["hips"]).max())
            pos, _ = motion.forward_kinematics()
            nodes = [skel.node_names.index(str(n)) for n in g["joint_names"]]
            d_fk = np.linalg.norm(pos[:, nodes] - (g["joint_xpos"] + c["shift"]), axis=-1)
            rb = per_clip[label][c["name"]]["own_rot_bodies"]
            worst = max(rb, key=rb.get)
            checks.append(f"{label} {c['name']}: height {float(g['height']):.3f} m; standing frame {c['standing_frame']}; "
                          f"GMR's orientation error to its own goals {float(g['own_rot']):.1f} deg (worst {worst} {rb[worst]:.0f}); "
                          f"GMR's hips vs mer's reading of the file: max {1e3 * d_in:.3f} mm; GMR's MJCF vs mer's URDF joint "
                          f"positions on GMR's angles: mean {1e3 * d_fk.mean():.2f} mm, max {1e3 * d_fk.max():.2f} mm")  # fmt: skip
    order = [k for k in (*gmr_labels, *(f"mer {m}" for m in args.mer_methods)) if k in per_clip]
    summary = {k: summarize(list(per_clip[k].values())) for k in order}
    print_table(summary, {k: per_clip[k] for k in order}, names)
    load = os.getloadavg()[0]
    print(f"\nchecks ({os.cpu_count()} CPUs, {args.threads} threads; load average {load0:.2f} at the start, {load:.2f} at "
          "the end: with more threads than idle cores, mer's timings suffer, GMR's one-thread loop's hardly):")  # fmt: skip
    for line in checks or ["(no GMR output)"]:
        print("  " + line)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)

        def clean(d: dict[str, Any]) -> dict[str, Any]:
            return {k: (v if isinstance(v, (str, list, dict)) or v is None else float(v)) for k, v in d.items()}

        args.json.write_text(json.dumps({
            "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}, "summary": summary,
            "per_clip": {k: {c: clean(v) for c, v in per_clip[k].items()} for k in order},
            "gmr_offsets": {c: g.get("offsets") for c, g in (gmr_outs[0] if gmr_outs else {}).items() if "offsets" in g},
            "checks": checks,
        }, indent=1) + "\n")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
