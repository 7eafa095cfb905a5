"""Maintainer script: (re)build the built-in robots from ``../shared/robots``.

Copies each URDF and its upstream LICENSE into ``mer_data/robots/<name>/`` and writes its robot card
from the verified key-point reading (``keypoints.reference.json``), the LAFAN1 column order
(``../shared/data/lafan1/FORMAT.json``) and the locked joints listed below. The key points are
checked against forward kinematics of the URDF (zero pose, root frame) before anything is written.

    python tools/import_builtin_robots.py [--shared ../shared]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mer_data.robots.builder import build_skeleton, zero_pose_link_transforms  # noqa: E402
from mer_data.robots.card import DEFAULT_BODY_PARTS, KeypointSpec, RobotCard, dump_card  # noqa: E402
from mer_data.robots.urdf import load_urdf  # noqa: E402
from mer_data.skeleton import KEYPOINTS  # noqa: E402

META = {
    "g1": ("Unitree G1, 29 DoF, rev 1.0", "BSD-3-Clause",
           "unitreerobotics/unitree_ros robots/g1_description/g1_29dof_rev_1_0.urdf @ d6f13aad"),
    "h1": ("Unitree H1 (no hands)", "BSD-3-Clause",
           "unitreerobotics/unitree_ros robots/h1_description/urdf/h1.urdf @ d6f13aad"),
    "h1_2": ("Unitree H1_2 (no hands)", "BSD-3-Clause",
             "unitreerobotics/unitree_ros robots/h1_2_description/h1_2_handless.urdf @ d6f13aad"),
    "atlas": ("Boston Dynamics Atlas v5 with MultiSense head (xacro expanded)", "Apache-2.0",
              "osrf/drcsim atlas_description/robots/atlas_v5.urdf.xacro @ 020259c1"),
    "oli": ("LimX Oli, HU_D04_01", "Apache-2.0",
            "limxdynamics/humanoid-description HU_D04_description/urdf/HU_D04_01.urdf @ 63eaa67b"),
    "tron1": ("LimX TRON1, sole feet (SF_TRON1A), biped without arms", "Apache-2.0",
              "limxdynamics/robot-description pointfoot/SF_TRON1A/urdf/robot.urdf @ 469df8db"),
    "talos": ("PAL TALOS full_v2 (xacro expanded with the launch defaults)",
              "Apache-2.0 (older file headers say CC BY-NC-ND 3.0; see LICENSE)",
              "pal-robotics/talos_robot talos_description/robots/talos_full_v2.urdf.xacro @ 221f9169"),
    "valkyrie": ("NASA Valkyrie, unit A", "NASA-1.3",
                 "gkjohnson/nasa-urdf-robots val_description/model/robots/valkyrie_A.urdf @ 1f89ecba"),
}  # fmt: skip

VALKYRIE_FINGERS = [
    f"{side}{finger}"
    for side in ("left", "right")
    for finger in (
        "ThumbRoll", "ThumbPitch1", "ThumbPitch2", "ThumbPitch3",
        "IndexFingerPitch1", "IndexFingerPitch2", "IndexFingerPitch3",
        "MiddleFingerPitch1", "MiddleFingerPitch2", "MiddleFingerPitch3",
        "PinkyPitch1", "PinkyPitch2", "PinkyPitch3",
    )
]  # fmt: skip

LOCKED = {
    "atlas": {"hokuyo_joint": 0.0},  # lidar spindle
    "talos": {"gripper_left_joint": 0.0, "gripper_right_joint": 0.0},  # its 12 mimic joints follow
    "valkyrie": {name: 0.0 for name in VALKYRIE_FINGERS},
}

NOTES = {
    "h1": "H1 has no wrist or hand link: the hand key point is the hand mount of h1_with_hand.urdf "
    "(elbow link + offset).",
    "tron1": "No arms: shoulder, elbow and hand are absent. Toe offset read off the SF ankle mesh bounds.",
    "talos": "Grippers locked open at 0; their mimic joints follow. Toe = front edge of the sole.",
    "valkyrie": "The 26 finger joints are locked at 0 (not body joints).",
    "atlas": "Joints are listed alphabetically in the URDF; node order follows the tree, not the file.",
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    args = ap.parse_args()
    robots = args.shared / "robots"
    ref = json.loads((robots / "keypoints.reference.json").read_text())
    columns = json.loads((args.shared / "data/lafan1/FORMAT.json").read_text())["columns"]
    for name, (desc, lic, src) in META.items():
        out = ROOT / "mer_data/robots" / name
        out.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(robots / name / f"{name}.urdf", out / f"{name}.urdf")
        shutil.copyfile(robots / name / "LICENSE", out / "LICENSE")
        kps = {}
        for k in KEYPOINTS:
            r = ref[name].get(k)
            kps[k] = None if r is None else KeypointSpec(r["link"], tuple(r.get("offset", (0.0, 0.0, 0.0))))
        cols = columns.get(name)
        card = RobotCard(
            name=name,
            urdf=f"{name}.urdf",
            keypoints=kps,
            locked=LOCKED.get(name, {}),
            body_parts=DEFAULT_BODY_PARTS,
            lafan1_columns=None if cols is None else tuple(cols[7:]),
            description=desc,
            license=lic,
            source=src,
            notes=NOTES.get(name, ""),
        )
        urdf = load_urdf(out / f"{name}.urdf")
        skel = build_skeleton(urdf, card)
        # verify the key points against the reading's zero-pose positions (1 mm: the reading rounds)
        t_root = zero_pose_link_transforms(urdf, dict(skel.locked))
        rest = skel.rest_positions
        for k, node in skel.keypoints.items():
            r = ref[name].get(k)
            if r is None:
                assert node == -1, (name, k)
                continue
            expect = np.asarray(r["pos_zero_pose_in_root"])
            assert np.abs(rest[node] - expect).max() < 1e-3, (name, k, rest[node], expect)
            t = t_root[r["link"]]
            assert np.allclose(t[:3, :3] @ np.asarray(r.get("offset", (0, 0, 0))) + t[:3, 3], rest[node])
        if cols is not None:
            missing = set(cols[7:]) ^ set(skel.joint_names)
            assert not missing, (name, missing)
        (out / "robot.yaml").write_text(f"# Robot card of the built-in robot {name!r}; see docs/robots.md.\n" + dump_card(card))
        print(f"{name:9s} {skel}")


if __name__ == "__main__":
    main()
