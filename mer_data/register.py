"""``mer robots register``: a new robot from its URDF, in one call, with no code change."""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from .errors import RobotCardError
from .keypoint_proposal import KeypointProposal, propose_keypoints
from .registry import Robot, validate_robot_name, write_robot
from .robot_card import DEFAULT_BODY_PARTS, RobotCard, parse_keypoints
from .safe_io import decode_utf8, read_regular_file, safe_yaml_load
from .skeleton import KEYPOINTS
from .skeleton_builder import build_skeleton
from .urdf import load_urdf

log = logging.getLogger(__name__)

__all__ = ["register_robot", "RegistrationReport", "parse_lock", "load_keypoints_file"]


@dataclass(frozen=True)
class RegistrationReport:
    robot: Robot
    proposals: dict[str, KeypointProposal] | None  # None when key points came from a file
    warnings: list[str] = field(default_factory=list)

    def summary(self) -> str:
        s = self.robot.skeleton
        sites = [n for n, k in zip(s.node_names, s.node_kinds) if k == "site"]
        mimic = [n for n, m in zip(s.node_names, s.mimic_source) if m >= 0]
        lines = [
            f"registered {s.name!r} from {self.robot.urdf_path}",
            f"  nodes {s.num_nodes} (base 1, joints {int(s.revolute_mask.sum())}, sites {len(sites)}), "
            f"actuated joints {s.num_dof}" + (f", mimic {len(mimic)}" if mimic else ""),
        ]
        if s.locked:
            lines.append(f"  locked: {', '.join(f'{k}={v:g}' for k, v in s.locked.items())}")
        lines.append("  key points:")
        for k in KEYPOINTS:
            node = s.keypoints[k]
            where = "absent" if node < 0 else f"{s.node_names[node]} ({s.node_kinds[node]})"
            if self.proposals is not None:
                p = self.proposals[k]
                lines.append(f"    {k:15s} {where:40s} [{p.confidence}] {p.reason}")
            else:
                lines.append(f"    {k:15s} {where}")
        if self.proposals is not None:
            unsure = [k for k, p in self.proposals.items() if p.confidence in ("low", "absent")]
            if unsure:
                lines.append(
                    f"  check: {', '.join(unsure)}. Correct them with --keypoints FILE "
                    "(YAML: name: {link: LINK, offset: [x, y, z]} or null) and --force."
                )
        lines.extend(f"  warning: {w}" for w in self.warnings)
        return "\n".join(lines)


def parse_lock(text: str) -> tuple[str, float]:
    """``JOINT=VALUE`` (radians) → (joint, value)."""
    name, sep, value = text.partition("=")
    try:
        if not sep or not name:
            raise ValueError
        return name.strip(), float(value)
    except ValueError:
        raise RobotCardError(f"--lock {text!r} is not JOINT=VALUE", fix="e.g. --lock hokuyo_joint=0") from None


def load_keypoints_file(path: str | Path) -> dict:
    """Key points from a YAML or JSON file: either the mapping itself or ``{keypoints: {...}}``."""
    path = Path(path)
    raw = read_regular_file(path, RobotCardError, "MER_MAX_CARD_BYTES", fix="check the path given to --keypoints")
    text = decode_utf8(raw, path, RobotCardError)
    try:
        data = json.loads(text) if path.suffix == ".json" else safe_yaml_load(text)
    except (ValueError, yaml.YAMLError, RecursionError) as exc:
        raise RobotCardError(f"cannot parse the key point file: {str(exc)[:300]}", path=path) from None
    if isinstance(data, dict) and "keypoints" in data:
        data = data["keypoints"]
    return parse_keypoints(data, str(path))


def register_robot(
    name: str,
    urdf_path: str | Path,
    *,
    keypoints_file: str | Path | None = None,
    locks: dict[str, float] | None = None,
    force: bool = False,
) -> RegistrationReport:
    """Validate a URDF, settle its key points, and install it in the registry atomically."""
    validate_robot_name(name)
    urdf_path = Path(urdf_path)
    urdf = load_urdf(urdf_path)
    locks = dict(locks or {})
    proposals = None
    if keypoints_file is not None:
        keypoints = load_keypoints_file(keypoints_file)
    else:
        proposals = propose_keypoints(urdf, locks)
        keypoints = {k: p.spec for k, p in proposals.items()}
    card = RobotCard(
        name=name,
        urdf=urdf_path.name,
        keypoints=keypoints,
        locked=locks,
        body_parts=DEFAULT_BODY_PARTS,
        description=f"{urdf.name} (registered from {urdf_path.name})",
        path=str(keypoints_file) if keypoints_file else None,
    )
    skel = build_skeleton(urdf, card)  # refuse before anything is written
    warnings = []
    if skel.num_dof == 0:
        warnings.append("the robot has no moving joint")
    present = sum(v >= 0 for v in skel.keypoints.values())
    if present < 4:
        warnings.append(f"only {present} key points: retargeting has little to follow")
    robot, _ = write_robot(card, urdf_path, force=force)
    log.info("registered %s", robot.skeleton)
    return RegistrationReport(robot, proposals, warnings)
