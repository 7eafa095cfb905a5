"""Run by mjlab's Python (not mer's) from tests/models/export/test_mjlab_env.py:

    python mjlab_check.py FOLDER PACKAGE MOTION.npz STEPS

Imports the package ``mer robots export --mjlab`` wrote in FOLDER (which registers its tracking
task), builds mjlab's motion-tracking environment for it on the CPU with MOTION.npz, resets it,
steps it STEPS times with zero actions, and prints one JSON line: the entity's joint and body
names, the tracked bodies, the largest difference between the reference bodies the environment's
motion command holds and the npz's bodies of the same names, and whether the state stayed finite.
"""

from __future__ import annotations

import importlib
import json
import sys
import time

import numpy as np
import torch


def main(folder: str, package: str, motion: str, steps: int) -> dict:
    sys.path.insert(0, folder)
    mod = importlib.import_module(package)
    from mjlab.envs import ManagerBasedRlEnv
    from mjlab.tasks.registry import list_tasks, load_env_cfg

    assert mod.TASK_ID in list_tasks(), list_tasks()
    cfg = load_env_cfg(mod.TASK_ID)
    cfg.scene.num_envs = 1
    cfg.commands["motion"].motion_file = motion
    t0 = time.perf_counter()
    env = ManagerBasedRlEnv(cfg=cfg, device="cpu")
    built = time.perf_counter() - t0
    env.reset()
    robot = env.scene["robot"]
    cmd = env.command_manager.get_term("motion")
    z = np.load(motion, allow_pickle=False)
    names = [str(n) for n in z["body_names"]]
    idx = [names.index(n) for n in cmd.cfg.body_names]
    ref = {k: getattr(cmd.motion, k).cpu().numpy() for k in ("body_pos_w", "body_quat_w", "body_lin_vel_w", "body_ang_vel_w")}
    diff = {k: float(np.abs(ref[k] - z[k][:, idx]).max()) for k in ref}
    diff["joint_pos"] = float(np.abs(cmd.motion.joint_pos.cpu().numpy() - z["joint_pos"]).max())
    actions = torch.zeros(env.num_envs, env.action_manager.total_action_dim)
    finite = True
    t0 = time.perf_counter()
    steps_done = 0
    for _ in range(steps):
        env.step(actions)
        steps_done += 1
        finite &= bool(torch.isfinite(robot.data.joint_pos).all() and torch.isfinite(robot.data.root_link_pos_w).all())
    stepped = time.perf_counter() - t0
    # after stepping: the command's reference at its current time step is the npz's frame
    t = int(cmd.time_steps[0])
    now = cmd.body_pos_w[0].cpu().numpy() - env.scene.env_origins[0].cpu().numpy()
    diff["body_pos_w_now"] = float(np.abs(now - z["body_pos_w"][t, idx]).max())
    env.close()
    # the play task (no randomisation) with the full joint range: reset puts the robot in the
    # motion's first frame; mjlab's forward kinematics of the folder's model puts every body where
    # the npz says
    play = load_env_cfg(mod.TASK_ID, play=True)
    play.scene.num_envs = 1
    play.commands["motion"].motion_file = motion
    play.commands["motion"].joint_position_range = (0.0, 0.0)
    play.scene.entities["robot"].articulation.soft_joint_pos_limit_factor = 1.0
    env = ManagerBasedRlEnv(cfg=play, device="cpu")
    env.reset()
    robot = env.scene["robot"]
    origin = env.scene.env_origins[0].cpu().numpy()
    pos = robot.data.body_link_pos_w[0].cpu().numpy() - origin
    quat = robot.data.body_link_quat_w[0].cpu().numpy()
    qz = z["body_quat_w"][0]
    kin = {
        "body_pos": float(np.abs(pos - z["body_pos_w"][0]).max()),
        "body_quat": float(np.minimum(np.abs(quat - qz).max(-1), np.abs(quat + qz).max(-1)).max()),
        "joint_pos": float(np.abs(robot.data.joint_pos[0].cpu().numpy() - z["joint_pos"][0]).max()),
    }
    return {
        "task": mod.TASK_ID,
        "joint_names": list(robot.joint_names),
        "body_names": list(robot.body_names),
        "npz_joint_names": [str(n) for n in z["joint_names"]],
        "npz_body_names": names,
        "tracked": list(cmd.cfg.body_names),
        "anchor": cmd.cfg.anchor_body_name,
        "num_actions": int(env.action_manager.total_action_dim),
        "num_actuators": int(robot.num_actuators),
        "fps": [float(z["fps"][0]), str(z["fps"].dtype)],
        "frames": int(z["joint_pos"].shape[0]),
        "diff": diff,
        "replay": kin,
        "steps": steps_done,
        "time_step": t,
        "finite": finite,
        "root_height": float(robot.data.root_link_pos_w[0, 2]),
        "seconds": {"build": round(built, 1), "steps": round(stepped, 1)},
    }


if __name__ == "__main__":
    out = main(sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]))
    print("MJLAB_CHECK " + json.dumps(out))
