"""The text files of an mjlab folder (:mod:`.mjlab`): the Python module with the entity config and
the tracking-task registration (for mjlab 1.6), its ``pyproject.toml``, and the README that lists
the numbers mer chose. The module reads its gains from the MJCF (``XmlActuatorCfg``), so the
numbers live in one place: edit the ``<position>`` elements to change them.
"""

from __future__ import annotations

from mer_data.robots.articulation import Articulation
from mer_data.robots.registry import Robot

from .mjlab_body import Standing, body_of_keypoint
from .mjlab_drive import Drive

__all__ = ["module_text", "pyproject_text", "readme_text"]

_MODULE = '''"""mjlab entity and motion-tracking task of {name!r}, written by `mer robots export {name} --mjlab DIR`.

The robot is `{name}.xml` beside this file (meshes/ and licences beside it too); its joints and
bodies are, in order, the `joint_names` / `body_names` of mer's npz for mjlab
(`mer retarget ... --target {name} --npz OUT.npz --npz-for mjlab`). Gains, effort limits and armature
are the MJCF's `<position>` actuators and joint attributes (README.md says which mer chose and how).

Train (mjlab 1.6): `pip install -e DIR` (registers {task!r} through mjlab's `mjlab.tasks` entry point), then
    train {task} --env.commands.motion.motion-file {pkg}/motions/CLIP.npz
"""

import re
from pathlib import Path

import mujoco

from mjlab.actuator import XmlActuatorCfg
from mjlab.entity import EntityArticulationInfoCfg, EntityCfg
from mjlab.utils.spec_config import CollisionCfg

XML = Path(__file__).parent / "{name}.xml"
TASK_ID = {task!r}
ROOT_BODY = {root!r}
ANCHOR_BODY = {anchor!r}
#: the bodies the task tracks (mer: the root and the bodies of its 14 key points, and the anchor)
TRACKED_BODIES = {tracked!r}
#: feet and hands: an episode ends when one is 0.25 m off the motion's height
END_EFFECTOR_BODIES = {ends!r}
FEET = r"^(left|right)_foot[0-9]+_collision$"
INIT_HEIGHT = {height!r}  # [m] the root's height with the lowest collision point on the floor
INIT_JOINT_POS = {init!r}  # [rad or m] (exact names; mjlab reads the keys as patterns)

FULL_COLLISION = CollisionCfg(
    geom_names_expr=(".*_collision",),
    contype=1,
    conaffinity=1,
    condim={{FEET: 3, ".*_collision": 1}},
    priority={{FEET: 1, ".*": 0}},
    friction={{FEET: (0.6,)}},
)


def get_spec() -> mujoco.MjSpec:
    return mujoco.MjSpec.from_file(str(XML))


def action_scale() -> dict[str, float]:
    """Per actuator 0.25 x effort limit / stiffness (the rule of mjlab's G1)."""
    out = {{}}
    spec = get_spec()  # kept alive while its actuators are read
    for a in spec.actuators:
        out["^" + re.escape(a.name) + "$"] = 0.25 * float(a.forcerange[1]) / float(a.gainprm[0])
    return out


def get_robot_cfg() -> EntityCfg:
    return EntityCfg(
        init_state=EntityCfg.InitialStateCfg(
            pos=(0.0, 0.0, INIT_HEIGHT),
            joint_pos={{"^" + re.escape(k) + "$": v for k, v in INIT_JOINT_POS.items()}},
            joint_vel={{".*": 0.0}},
        ),
        collisions=(FULL_COLLISION,),
        spec_fn=get_spec,
        articulation=EntityArticulationInfoCfg(
            actuators=(XmlActuatorCfg(target_names_expr=(".*",)),), soft_joint_pos_limit_factor=0.9
        ),
    )


def tracking_env_cfg(play: bool = False):
    """mjlab's tracking task (as its G1's) for this robot."""
    from mjlab.envs.mdp.actions import JointPositionActionCfg
    from mjlab.sensor import ContactMatch, ContactSensorCfg
    from mjlab.tasks.tracking.mdp import MotionCommandCfg
    from mjlab.tasks.tracking.tracking_env_cfg import make_tracking_env_cfg

    cfg = make_tracking_env_cfg()
    cfg.scene.entities = {{"robot": get_robot_cfg()}}
    cfg.scene.sensors = (
        ContactSensorCfg(
            name="self_collision",
            primary=ContactMatch(mode="subtree", pattern=ROOT_BODY, entity="robot"),
            secondary=ContactMatch(mode="subtree", pattern=ROOT_BODY, entity="robot"),
            fields=("found", "force"),
            reduce="none",
            num_slots=1,
            history_length=4,
        ),
    )
    action = cfg.actions["joint_pos"]
    assert isinstance(action, JointPositionActionCfg)
    action.scale = action_scale()
    motion = cfg.commands["motion"]
    assert isinstance(motion, MotionCommandCfg)
    motion.anchor_body_name = ANCHOR_BODY
    motion.body_names = TRACKED_BODIES
    cfg.events["foot_friction"].params["asset_cfg"].geom_names = FEET
    cfg.events["base_com"].params["asset_cfg"].body_names = (ANCHOR_BODY,)
    cfg.terminations["ee_body_pos"].params["body_names"] = END_EFFECTOR_BODIES
    cfg.viewer.body_name = ANCHOR_BODY
    if play:
        cfg.episode_length_s = int(1e9)
        cfg.observations["actor"].enable_corruption = False
        cfg.events.pop("push_robot", None)
        motion.pose_range = {{}}
        motion.velocity_range = {{}}
        motion.sampling_mode = "start"
    return cfg


def rl_cfg():
    """mjlab's PPO settings of its G1 tracking task, under this robot's experiment name."""
    from mjlab.tasks.tracking.config.g1.rl_cfg import unitree_g1_tracking_ppo_runner_cfg

    cfg = unitree_g1_tracking_ppo_runner_cfg()
    cfg.experiment_name = {experiment!r}
    return cfg


def register() -> None:
    """Register TASK_ID with mjlab (once)."""
    from mjlab.tasks.registry import list_tasks, register_mjlab_task
    from mjlab.tasks.tracking.rl import MotionTrackingOnPolicyRunner

    if TASK_ID not in list_tasks():
        register_mjlab_task(
            task_id=TASK_ID,
            env_cfg=tracking_env_cfg(),
            play_env_cfg=tracking_env_cfg(play=True),
            rl_cfg=rl_cfg(),
            runner_cls=MotionTrackingOnPolicyRunner,
        )


register()
'''

_PYPROJECT = """[build-system]
requires = ["setuptools>=61"]
build-backend = "setuptools.build_meta"

[project]
name = "{dist}"
version = "0.1.0"
description = "{name} for mjlab's motion tracking, written by `mer robots export {name} --mjlab`"
requires-python = ">=3.10"
dependencies = ["mjlab>=1.6"]

[project.entry-points."mjlab.tasks"]
{pkg} = "{pkg}"

[tool.setuptools]
packages = ["{pkg}"]

[tool.setuptools.package-data]
{pkg} = ["*.xml", "*.md", "LICEN*", "COPYING*", "NOTICE*", "meshes/*", "motions/*"]
"""


def module_text(robot: Robot, art: Articulation, st: Standing, init: dict[str, float], pkg: str, task: str) -> str:
    """The package's ``__init__.py``."""
    ends = []
    for key in ("left_ankle", "right_ankle", "left_hand", "right_hand"):
        b = body_of_keypoint(robot, art, key)
        if b is not None and art.bodies[b].name in st.tracked and art.bodies[b].name not in ends:
            ends.append(art.bodies[b].name)
    return _MODULE.format(name=robot.name, task=task, pkg=pkg, root=art.bodies[0].name, anchor=st.anchor,
                          tracked=tuple(st.tracked), ends=tuple(ends), height=round(float(st.height), 6),
                          init={k: round(v, 6) for k, v in init.items()}, experiment=f"{robot.name}_tracking")  # fmt: skip


def pyproject_text(pkg: str, name: str) -> str:
    return _PYPROJECT.format(dist=pkg.replace("_", "-"), name=name, pkg=pkg)


def readme_text(robot: Robot, art: Articulation, st: Standing, drives: list[Drive], pairs: list[tuple[str, str]],
                freq: float, zeta: float, radius: float, licences: list[str]) -> str:  # fmt: skip
    """What the user must still decide, with the numbers mer chose (docs/trackers.md §5)."""
    rows = "\n".join(
        f"| {d.joint} | {d.kp:.4g} | {d.kd:.4g} | {d.effort:.4g} ({d.source['effort']}) | {d.armature:.4g} ({d.source['armature']}) "
        f"| {d.source['gains']} |" for d in drives
    )  # fmt: skip
    feet = ", ".join(f"{side}: {', '.join(art.bodies[b].name for b in bodies)}" for side, bodies in st.foot_bodies.items())
    n = {side: sum(s.side == side for s in st.spheres) for side in st.foot_bodies}
    lic = ", ".join(licences) if licences else "none found: add the description's licence here"
    return f"""# {robot.name} for mjlab

Written by `mer robots export {robot.name} --mjlab`. Description: {robot.card.description or robot.name}
(licence: {robot.card.license or "unknown"}; source: {robot.card.source or "the registered file"}; files: {lic}).

## What mer chose (check these before training)

**Gains** ("rule": armature a = 1.334e-3 sqrt(effort), kp = a w^2, kd = 2 zeta a w, w = {freq:.4g} rad/s,
zeta = {zeta:g}; "given": from the description). Edit the `<position>` elements and joint `armature`
in {robot.name}.xml; the task's action scale is 0.25 effort / kp per actuator.

| joint | kp | kd | effort | armature | gains |
|---|---|---|---|---|---|
{rows}

**Feet**: {feet}; contact spheres of radius {radius} m at the corners of each sole
({", ".join(f"{k}: {v}" for k, v in n.items())}), named `<side>_foot<k>_collision` (condim 3, friction 0.6); the
feet's own shapes do not touch anything.

**Initial state**: root at {st.height:.4f} m (lowest collision point on the floor), joints at 0 inside 90 % of
their limits (locked joints at their values).

**Tracked bodies**: {", ".join(st.tracked)}; anchor: {st.anchor}.

**Excluded contacts** ({len(pairs)} body pairs: parent/child, and those touching at the initial pose):
{", ".join(f"{a}/{b}" for a, b in pairs)}.
"""
