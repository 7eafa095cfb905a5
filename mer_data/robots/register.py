"""``mer robots register``: a new robot from its URDF or MJCF, in one call, with no code change."""

from __future__ import annotations

import dataclasses
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import yaml

from mer_data.base.errors import MalformedURDFError, RobotCardError
from mer_data.base.safe_io import decode_utf8, read_regular_file, safe_yaml_load, strict_json_loads
from mer_data.base.sniff import expect as sniff_expect
from mer_data.skeleton import KEYPOINTS, Skeleton

from .builder import build_skeleton
from .card import DEFAULT_BODY_PARTS, KeypointSpec, RobotCard, parse_keypoints
from .keypoints import KeypointProposal, propose_robot
from .mjcf import description_format, load_mjcf, registry_copy
from .registry import CARD_FILE, Robot, validate_robot_name, write_robot
from .shapes import COLLISION_FILE, CollisionFile, dump_collision, shapes_from_urdf
from .urdf import UrdfModel, load_urdf

log = logging.getLogger(__name__)

__all__ = ["register_robot", "RegistrationReport", "parse_lock", "load_keypoints_file", "keypoints_yaml", "prismatic_locks"]


@dataclass(frozen=True)
class RegistrationReport:
    """What a registration did (or, with ``dry_run``, would do).

    ``robot`` is the installed entry (None on a dry run); ``skeleton``/``card`` what was (or would
    be) installed; ``warnings`` what was ignored or may surprise; ``notes`` the conventions applied.
    """

    robot: Robot | None
    proposals: dict[str, KeypointProposal] | None  # key points given in a file have confidence "given"
    warnings: list[str] = field(default_factory=list)
    skeleton: Skeleton | None = None
    card: RobotCard | None = None
    urdf_path: Path | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def card_path(self) -> Path | None:
        """Where the robot card was written (None on a dry run)."""
        return None if self.robot is None else self.robot.folder / CARD_FILE

    def to_check(self) -> list[str]:
        """Key points worth a look: estimates (``low``) and absences that are not by design (not a point foot's toe)."""
        return [k for k, p in (self.proposals or {}).items() if p.needs_check]

    def summary(self) -> str:
        """What was registered, each key point with its confidence, what to check and where the card is."""
        s = self.skeleton if self.skeleton is not None else self.robot.skeleton
        sites = [n for n, k in zip(s.node_names, s.node_kinds) if k == "site"]
        mimic = [n for n, m in zip(s.node_names, s.mimic_source) if m >= 0]
        head = "registered" if self.robot is not None else "dry run, nothing written: would register"
        lines = [
            f"{head} {s.name!r} from {self.urdf_path or self.robot.urdf_path}",
            f"  nodes {s.num_nodes} (base 1, joints {int(s.revolute_mask.sum())}, sites {len(sites)}), "
            f"actuated joints {s.num_dof}" + (f", mimic {len(mimic)}" if mimic else ""),
        ]
        if s.locked:
            lines.append(f"  locked ({len(s.locked)}): {', '.join(f'{k}={v:g}' for k, v in s.locked.items())}")
        lines.append("  key points:")
        for k in KEYPOINTS:
            node = s.keypoints[k]
            where = "absent" if node < 0 else f"{s.node_names[node]} ({s.node_kinds[node]})"
            if self.proposals is not None:
                p = self.proposals[k]
                conf = f"{p.confidence}, by design" if p.by_design else p.confidence
                lines.append(f"    {k:15s} {where:40s} [{conf}] {p.reason}")
            else:
                lines.append(f"    {k:15s} {where}")
        lines.extend(f"  note: {n}" for n in self.notes)
        unsure = self.to_check()
        if unsure:
            lines.append(
                f"  check: {', '.join(unsure)}. Correct them with --keypoints FILE and --force: a YAML file of "
                "only the key points that change (name: {link: LINK, offset: [x, y, z]} or null), "
                f"merged over this proposal" + (f"; `mer robots keypoints {s.name} --write FILE` writes the current set"
                                                 if self.robot is not None else "")
            )
        lines.extend(f"  warning: {w}" for w in self.warnings)
        if self.card_path is not None:
            lines.append(f"  robot card: {self.card_path}")
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


def load_keypoints_file(path: str | Path) -> dict[str, KeypointSpec | None]:
    """Key points from a YAML or JSON file: either the mapping itself or ``{keypoints: {...}}``.

    Returns only the key points the file gives (``None`` for ``name: null``, absent); any subset
    of the 14 is allowed: registration merges it over the proposal.
    """
    path = Path(path)
    raw = read_regular_file(path, RobotCardError, "MER_MAX_CARD_BYTES", fix="check the path given to --keypoints")
    text = decode_utf8(raw, path, RobotCardError)
    try:
        data = strict_json_loads(text) if path.suffix == ".json" else safe_yaml_load(text)
    except (ValueError, yaml.YAMLError, RecursionError) as exc:
        raise RobotCardError(f"cannot parse the key point file: {str(exc)[:300]}", path=path) from None
    if isinstance(data, dict) and "keypoints" in data:
        data = data["keypoints"]
    if data is None or (isinstance(data, dict) and not data):
        raise RobotCardError("the key point file gives no key point", path=path, element="keypoints",
                             fix=f"give the key points that change, e.g. `left_toe: {{link: LINK, offset: [x, y, z]}}` "
                             f"(names: {', '.join(KEYPOINTS)})")  # fmt: skip
    parsed = parse_keypoints(data, str(path), require_all=False)
    return {k: v for k, v in parsed.items() if k in data}


def _tag(value: object) -> str:
    """A YAML flow value for the key-point file, with lists inline."""
    return yaml.safe_dump(value, default_flow_style=True, sort_keys=False, width=1000).strip()


def keypoints_yaml(robot: Robot) -> str:
    """The robot's 14 key points as an editable key-point file (``--keypoints FILE``), with a comment header.

    Each line ends with a comment naming the skeleton node it is (a joint, or a site). Loading the
    text with :func:`load_keypoints_file` gives the card's key points back exactly.
    """
    s = robot.skeleton
    flag = "--mjcf" if description_format(robot.urdf_path) == "mjcf" else "--urdf"
    if robot.builtin:
        again = f"mer robots register my_{robot.name} {flag} {robot.urdf_path} --keypoints THIS_FILE"
        why = f"{robot.name!r} is built in: register a copy under another name"
    else:
        m = re.search(r"registered from ([^,)]+)", robot.card.description)
        again = f"mer robots register {robot.name} {flag} PATH/TO/{m.group(1) if m else robot.urdf_path.name} --keypoints THIS_FILE --force"
        why = "Register it again from the file you registered it from (the registry keeps no meshes)"
    lines = [
        f"# Key points of robot {robot.name!r}: {robot.card.description or robot.urdf_path.name}",
        "# Each is a link of the robot's description with an optional offset [m] in the link's frame, or null",
        "# (the robot has none); the comment names the skeleton node it became. Edit what is wrong and",
        "# register it again; a line you delete keeps the proposal's key point (a file of only the key points",
        f"# that change is enough). {why}:",
        f"#   {again}",
    ]
    rows = []
    for k in KEYPOINTS:
        spec = robot.card.keypoints.get(k)
        node = s.keypoints[k]
        if spec is None:
            rows.append((k, "null", "absent"))
            continue
        d: dict[str, object] = {"link": spec.link}
        if any(spec.offset):
            d["offset"] = [float(x) for x in spec.offset]
        if spec.note:
            d["note"] = spec.note
        rows.append((k, _tag(d), f"{s.node_names[node]} ({s.node_kinds[node]})" if node >= 0 else "absent"))
    width = max(len(k) for k in KEYPOINTS) + 1
    value_width = max(len(v) for _, v, _ in rows)
    lines += [f"{k + ':':{width}s} {v:{value_width}s}  # {where}" for k, v, where in rows]
    return "\n".join(lines) + "\n"


def prismatic_locks(urdf: UrdfModel, locks: dict[str, float]) -> dict[str, float]:
    """Prismatic joints the user did not lock, held at 0 clipped into their limits (skeletons only turn)."""
    out = {}
    for j in urdf.joints:
        if j.type == "prismatic" and j.name not in locks:
            lo = -np.inf if j.lower is None else j.lower
            hi = np.inf if j.upper is None else j.upper
            out[j.name] = float(np.clip(0.0, lo, hi))
    return out


def register_robot(
    name: str,
    urdf_path: str | Path,
    *,
    keypoints_file: str | Path | None = None,
    locks: dict[str, float] | None = None,
    force: bool = False,
    dry_run: bool = False,
    expect: Literal["urdf", "mjcf"] | None = None,
) -> RegistrationReport:
    """Validate a URDF or MJCF, settle its key points and locks, and install it in the registry atomically.

    The format is read from the file (a ``<mujoco>`` root is MJCF, :mod:`~mer_data.robots.mjcf`);
    ``expect`` (``"urdf"`` or ``"mjcf"``, what the user said) only adds a note where it differs.
    Without ``keypoints_file`` the key points are proposed and finger joints locked
    (:func:`~mer_data.robots.keypoints.propose_robot`); prismatic joints not in ``locks`` are
    locked at 0 in any case. ``dry_run`` validates and reports without writing anything.
    """
    validate_robot_name(name)
    urdf_path = Path(urdf_path)
    sniff_expect(urdf_path, ("urdf", "mjcf", "xml", "text", "binary", "empty"), "a robot description (URDF or MJCF)",
                 "give the robot's .urdf, or its MJCF .xml with --mjcf", MalformedURDFError)  # a BVH, an image...: named
    fmt = description_format(urdf_path)
    notes: list[str] = []
    if expect is not None and expect != fmt:
        notes.append(f"{urdf_path.name} is {'an MJCF model (<mujoco> root)' if fmt == 'mjcf' else 'a URDF (not <mujoco>)'}, "
                     f"given as --{expect}: read as {fmt.upper()}")  # fmt: skip
        log.info("%s", notes[-1])
    stored, extra = None, {}
    if fmt == "mjcf":
        urdf = load_mjcf(urdf_path)
        stored, extra = registry_copy(urdf_path)  # self-contained: includes expanded, sub-models beside it
    else:
        urdf = load_urdf(urdf_path)
    kind = "MJCF" if fmt == "mjcf" else "URDF"
    locks = dict(locks or {})
    warnings = list(urdf.warnings)
    sliding = prismatic_locks(urdf, locks)
    if sliding:
        warnings.append(
            f"prismatic joint(s) {', '.join(f'{k}={v:g}' for k, v in sliding.items())} locked "
            "(mer's skeletons have turning joints only; --lock JOINT=VALUE holds one elsewhere)"
        )
    locks = {**sliding, **locks}
    given = load_keypoints_file(keypoints_file) if keypoints_file is not None else {}
    proposal = propose_robot(urdf, locks)
    notes.extend(proposal.notes)
    locks = {**proposal.locked, **locks}  # the user's --lock wins
    proposals = dict(proposal.keypoints)
    for k, spec in given.items():  # the file's key points win over the proposal
        proposals[k] = KeypointProposal(k, spec, "given", f"from {Path(keypoints_file).name}")
    keypoints = {k: proposals[k].spec for k in KEYPOINTS}
    card = RobotCard(
        name=name,
        urdf=urdf_path.name,
        keypoints=keypoints,
        locked=locks,
        body_parts=DEFAULT_BODY_PARTS,
        description=f"{urdf.name} (registered from {urdf_path.name}{', MJCF' if fmt == 'mjcf' else ''})",
        path=str(keypoints_file) if keypoints_file else None,
    )
    skel = build_skeleton(urdf, card)  # refuse before anything is written
    if skel.num_dof == 0:
        warnings.append("the robot has no moving joint")
    present = sum(v >= 0 for v in skel.keypoints.values())
    if present < 4:
        warnings.append(f"only {present} key points: retargeting has little to follow")
    shapes, errors = shapes_from_urdf(urdf)  # URDF: meshes under its folder only; MJCF: MuJoCo's vertices; as hulls
    # an MJCF's unreadable mesh files were named by load_mjcf already (with the bodies concerned)
    told = {link for link, es in urdf.collisions.items() if any(e.get("vertices", ()) is None for e in es)}
    untold = [link for link in shapes.missing if link not in told]
    if untold:
        where = "under its folder" if fmt == "urdf" else "under its meshdir"
        warnings.append(
            f"collision meshes of {len(untold)} link(s) could not be read ({', '.join(untold[:6])}"
            f"{', ...' if len(untold) > 6 else ''}): those bodies get capsules fitted along the links "
            f"(put the meshes where the {kind} points, {where}, and register again with --force)"
        )
    if shapes.links:
        shapes = CollisionFile(name, shapes.links, f"registered from {urdf_path.name}: primitives as in the {kind}, meshes as "
                               f"convex hulls (at most 48 vertices, worst error {1000 * max(errors.values(), default=0.0):.1f} mm)",
                               shapes.missing)  # fmt: skip
        card = dataclasses.replace(card, collision=COLLISION_FILE)
        extra[COLLISION_FILE] = dump_collision(shapes)
    if dry_run:
        return RegistrationReport(None, proposals, warnings, skel, card, urdf_path, notes)
    robot, _ = write_robot(card, urdf_path, force=force, extra_files=extra, description=stored)
    log.info("registered %s", robot.skeleton)
    return RegistrationReport(robot, proposals, warnings, robot.skeleton, card, urdf_path, notes)
