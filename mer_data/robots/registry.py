"""The robot registry: name → (robot card, URDF or MJCF, skeleton).

Built-in robots ship inside the package (``mer_data/robots/<name>/``). User robots live in the
platform's user-data folder (``~/.local/share/mer/robots/<name>/`` on Linux), or under
``$MER_HOME/robots/<name>/`` when ``MER_HOME`` is set (:mod:`mer_data.robots.location`; robots
left in the old cache-folder registry are moved there once), and are used by name everywhere the
built-ins are.

A robot registered from an MJCF keeps it as ``<name>.xml`` (its ``<include>`` files expanded
into it; meshes are not copied, their hulls are in ``collision.json``): the card's ``urdf`` field
names that file, and :func:`load_robot` reads it with :func:`~mer_data.robots.mjcf.load_mjcf`
(kinematics only). URDF robots are stored and read as before.

Registration is atomic: the new entry is written and validated in a temporary folder beside the
registry and renamed into place; a failure or an interruption leaves no half-written entry.
Registrations may run concurrently in several processes: each temporary folder names its owner, and
the sweep of leftovers removes only those of processes that are gone. ``force`` replaces an entry
in one atomic exchange (Linux), or in two renames that are undone if the process dies between them.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import re
import shutil
import threading
from dataclasses import dataclass
from pathlib import Path

from mer_data.base.atomic import atomic_dir, recover_dir, sweep_stale, trash_dir
from mer_data.base.errors import RegistryError, RobotCardError, RobotExistsError, UnknownRobotError
from mer_data.base.suggest import close_matches, did_you_mean
from mer_data.skeleton import Skeleton

from .builder import build_skeleton
from .card import RobotCard, dump_card, load_card
from .location import legacy_robots_dir, robots_dir
from .mjcf import description_format, load_mjcf
from .urdf import UrdfModel, load_urdf

log = logging.getLogger(__name__)

__all__ = [
    "BUILTIN_ROBOTS",
    "Robot",
    "mer_home",
    "robots_dir",
    "list_robots",
    "load_robot",
    "get_skeleton",
    "write_robot",
    "unregister_robot",
    "validate_robot_name",
    "lookup_name",
    "known_names",
]

BUILTIN_ROBOTS: tuple[str, ...] = ("g1", "h1", "h1_2", "atlas", "oli", "tron1", "talos", "valkyrie")
_BUILTIN_DIR = Path(__file__).resolve().parent / "builtin"
_NAME = re.compile(r"^[a-z][a-z0-9_-]{0,63}$")
CARD_FILE = "robot.yaml"


def mer_home() -> Path:
    """``$MER_HOME``, else the platform's user cache folder + ``mer`` (caches: model cards, downloads)."""
    env = os.environ.get("MER_HOME")
    if env:
        return Path(env).expanduser()
    return legacy_robots_dir().parent


def validate_robot_name(name: str) -> str:
    """Names are lower-case identifiers: no path separators, no traversal out of the registry.

    This is the rule for *registering* a name; looking one up ignores case (:func:`lookup_name`).
    """
    if not isinstance(name, str) or not _NAME.match(name):
        lower = name.lower() if isinstance(name, str) else None
        hint = f" (robot names are lower-case: {lower!r})" if lower is not None and _NAME.match(lower) else ""
        raise RegistryError(
            f"invalid robot name {name!r}{hint}",
            fix="use 1-64 characters: a lower-case letter, then lower-case letters, digits, '_' or '-'",
        )
    return name


def lookup_name(name: str) -> str:
    """The registry's name for ``name`` as typed: case is ignored (``G1`` is ``g1``); validated."""
    return validate_robot_name(name.lower() if isinstance(name, str) else name)


@dataclass(frozen=True)
class Robot:
    """A registered robot: its card, description (``urdf_path``: a URDF, or an MJCF ``.xml``) and skeleton."""

    name: str
    card: RobotCard
    urdf_path: Path
    skeleton: Skeleton
    builtin: bool

    @property
    def folder(self) -> Path:
        return self.urdf_path.parent


def _user_names() -> list[str]:
    d = robots_dir()
    if not d.is_dir():
        return []
    return sorted(p.name for p in d.iterdir() if p.is_dir() and _NAME.match(p.name) and (p / CARD_FILE).is_file())


def known_names() -> list[str]:
    """Every robot name, built-ins first: folder names only, no card or description is read (fast)."""
    return list(BUILTIN_ROBOTS) + [n for n in _user_names() if n not in BUILTIN_ROBOTS]


def _folder_of(name: str) -> tuple[Path, bool]:
    """The folder of robot ``name`` (case ignored) and whether it is built in; UnknownRobotError otherwise."""
    typed = name
    name = name.lower() if isinstance(name, str) else name
    if name in BUILTIN_ROBOTS:
        return _BUILTIN_DIR / name, True
    validate_robot_name(name)
    folder = robots_dir() / name
    if (folder / CARD_FILE).is_file() or (recover_dir(folder) and (folder / CARD_FILE).is_file()):
        return folder, False
    known = known_names()
    hint = did_you_mean(typed, known)
    register = f"register it with `mer robots register {name} --urdf ROBOT.urdf` (or --mjcf ROBOT.xml)"
    raise UnknownRobotError(
        f"unknown robot {typed!r}; " + (f"{hint} (known robots: {', '.join(known)})" if hint else f"known robots: {', '.join(known)}"),
        fix=f"use {near[0]!r}, or {register}" if (near := close_matches(typed, known)) else register,
    )


def _load_description(path: Path) -> UrdfModel:
    """A stored description: an MJCF (kinematics only: its meshes are not stored) or a URDF."""
    return load_mjcf(path, geometry=False) if description_format(path) == "mjcf" else load_urdf(path)


_cache: dict[tuple, Robot] = {}
_lock = threading.Lock()


def load_robot(name: str) -> Robot:
    """Look a robot up by name (built-in or registered; case ignored); cached per file modification times.

    An unknown name raises :class:`UnknownRobotError` with the closest known names ("did you mean").
    """
    folder, builtin = _folder_of(name)
    name = folder.name  # the registry's own (lower-case) name, whatever case was typed
    card_path = folder / CARD_FILE
    key = (str(card_path), *(p.stat().st_mtime_ns for p in (card_path, *folder.glob("*.urdf"), *folder.glob("*.xml"))))
    with _lock:
        hit = _cache.get(key)
    if hit is not None:
        return hit
    card = load_card(card_path)
    if card.name != name:
        raise RobotCardError(
            f"the card is named {card.name!r} but lives in the folder of {name!r}",
            path=card_path,
            element="name",
            fix=f"set `name: {name}`",
        )
    urdf_path = folder / card.urdf
    robot = Robot(name, card, urdf_path, build_skeleton(_load_description(urdf_path), card), builtin)
    with _lock:
        _cache[key] = robot
    return robot


def as_robot(robot: str | Robot) -> Robot:
    """A robot resolved once, where a command or a public entry point starts: a name is looked up
    (:func:`load_robot`), a :class:`Robot` passes through. Lower layers take the :class:`Robot`."""
    return robot if isinstance(robot, Robot) else load_robot(robot)


def get_skeleton(name: str) -> Skeleton:
    """The skeleton of a registered robot."""
    return load_robot(name).skeleton


def list_robots() -> list[Robot]:
    """All robots, built-ins first. A broken user entry is logged and skipped, not fatal."""
    out = []
    for name in known_names():
        try:
            out.append(load_robot(name))
        except Exception as exc:  # noqa: BLE001 - one bad entry must not hide the others
            log.warning("robot %r is broken and is skipped: %s", name, exc)
    return out


def _sweep_stale() -> None:
    """Recover interrupted replacements and remove leftovers of registrations whose process is gone.

    Temporary folders of registrations still running (in this or another process) are kept.
    """
    d = robots_dir()
    if d.is_dir():
        for p in sweep_stale(d):
            log.info("removed the leftover %s of an interrupted registration", p.name)


def write_robot(
    card: RobotCard,
    urdf_source: Path,
    *,
    force: bool = False,
    extra_files: dict[str, str] | None = None,
    description: str | None = None,
) -> tuple[Robot, UrdfModel]:
    """Validate ``card`` + description and install them as a user robot, atomically.

    A URDF's bytes are copied as they are and the card is written with ``urdf: <name>.urdf``; an
    MJCF (``<mujoco>`` root) is stored as ``<name>.xml``, its text given as ``description`` (the
    file with its includes expanded, :func:`~mer_data.robots.mjcf.expand_includes`) or else copied.
    ``extra_files`` (file name → text, e.g. the card's ``collision.json``) are written beside them.

    Raises:
        RegistryError: invalid or built-in name; RobotExistsError: taken and not ``force``;
        any URDF/card error from validation (nothing is written then).
    """
    name = validate_robot_name(card.name)
    if name in BUILTIN_ROBOTS:
        raise RegistryError(
            f"{name!r} is a built-in robot and cannot be replaced", fix="register it under another name"
        )
    root = robots_dir()
    final = root / name
    if final.exists() and not force:
        raise RobotExistsError(
            f"robot {name!r} is already registered (at {final})",
            fix="pass --force to replace it, or choose another name",
        )
    root.mkdir(parents=True, exist_ok=True)
    _sweep_stale()
    urdf_name = f"{name}.xml" if description_format(urdf_source) == "mjcf" else f"{name}.urdf"
    parsed = {}

    def write(tmp: Path) -> None:
        if description is not None:
            (tmp / urdf_name).write_text(description, encoding="utf-8")
        else:
            shutil.copyfile(urdf_source, tmp / urdf_name)
        written_card = dataclasses.replace(card, urdf=urdf_name, path=str(tmp / CARD_FILE))
        (tmp / CARD_FILE).write_text(dump_card(written_card))
        for fname, text in (extra_files or {}).items():
            if Path(fname).name != fname or fname in (CARD_FILE, urdf_name):
                raise ValueError(f"extra robot file {fname!r} must be a plain file name other than the card's and the URDF's")
            (tmp / fname).write_text(text, encoding="utf-8")
        # validate exactly what was written, before it becomes visible
        parsed["urdf"] = _load_description(tmp / urdf_name)
        build_skeleton(parsed["urdf"], load_card(tmp / CARD_FILE))

    try:
        atomic_dir(final, write, replace=force)
    except FileExistsError:
        raise RobotExistsError(
            f"robot {name!r} was registered by another process meanwhile (at {final})",
            fix="pass --force to replace it, or choose another name",
        ) from None
    urdf = parsed["urdf"]
    return load_robot(name), urdf


def unregister_robot(name: str) -> Path:
    """Remove a user robot; returns the folder that was removed."""
    if isinstance(name, str) and name.lower() in BUILTIN_ROBOTS:
        raise RegistryError(f"{name!r} is a built-in robot and cannot be unregistered")
    folder, _ = _folder_of(name)
    try:
        trash_dir(folder)  # atomic: the name disappears at once
    except FileNotFoundError:
        raise UnknownRobotError(f"robot {name!r} was unregistered by another process meanwhile") from None
    return folder
