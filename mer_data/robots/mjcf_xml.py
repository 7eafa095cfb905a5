"""An MJCF's XML read safely before MuJoCo sees it: includes expanded, every file confined to the
model's folder, and what ``<replicate>`` / ``<flexcomp>`` would make counted.

MuJoCo reads files named by the model (``<include>``, ``<asset><model>``, meshes, height fields,
textures, skins, flexcomp meshes) relative to the folders MuJoCo's own rules give: includes
against the main model's folder, assets against ``<compiler meshdir|texturedir|assetdir>`` (itself
relative to the model's folder), ``<model file>`` against the **working directory** when the text is
given as a string. Here each is resolved as MuJoCo would against the model's folder, symbolic
links followed, and refused (:class:`MalformedURDFError` naming the element and line) when it lands
outside that folder (or a folder the caller adds, e.g. ``mer view --mesh-dir``). ``<model file>``
is rewritten to the absolute path of the file so found, so the working directory never matters.

MuJoCo expands ``<replicate count>`` and ``<flexcomp count>`` while it parses, with no limit: a
573-byte file with three nested ``replicate count="1000"`` asks for a billion bodies. The tree is
pre-walked and the elements it WOULD make (each element times the counts of the replicates around
it; a flexcomp's or composite's points; an attached sub-model's elements) are counted against
``MER_MAX_MJCF_ELEMENTS`` before MuJoCo is called.
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from lxml import etree

from mer_data.base.errors import MalformedURDFError
from mer_data.base.limits import limit, too_big
from mer_data.base.numbers import parse_count
from mer_data.base.safe_io import read_regular_file

from .urdf_checks import _check_depth, _check_unsafe, check_size

__all__ = ["ExpandedMjcf", "expand_mjcf", "expand_includes", "registry_copy", "description_format", "MAX_INCLUDE_DEPTH"]

MAX_INCLUDE_DEPTH = 16
#: Attributes naming a file that MuJoCo reads at compile time (``<include>`` and ``<model>`` apart).
_FILE_ATTRS = ("file", "fileright", "fileleft", "fileup", "filedown", "filefront", "fileback")
_DIRS = ("meshdir", "texturedir", "assetdir")
_FIX_OUT = "keep every file the model uses inside the model's folder (copy it in), with relative paths"


def _read_xml(path: Path, what: str, budget: list[int] | None = None) -> etree._Element:
    """A ``<mujoco>`` document: regular file, size and line limits, no DTD/entities, depth limit.

    ``budget``: bytes left for the main file and all its includes together (one file included many
    times counts each time, so nested includes cannot multiply past ``MER_MAX_URDF_BYTES``).
    """
    data = read_regular_file(path, MalformedURDFError, "MER_MAX_URDF_BYTES", fix=f"check the path of the {what}")
    check_size(data, str(path))
    if budget is not None:
        budget[0] -= len(data)
        if budget[0] < 0:
            msg, fix = too_big("MER_MAX_URDF_BYTES", limit("MER_MAX_URDF_BYTES") - budget[0])
            raise MalformedURDFError(f"{msg} (the model with its <include> files, each counted every time it is included)",
                                     path=path, fix=fix)  # fmt: skip
    _check_unsafe(data, str(path))
    parser = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False, huge_tree=False)
    try:
        root = etree.fromstring(data, parser)
    except etree.XMLSyntaxError as exc:
        raise MalformedURDFError(f"not well-formed XML: {exc.msg}", path=path, line=exc.lineno,
                                 fix="repair the XML (an unclosed tag or stray character is the usual cause)") from None  # fmt: skip
    except ValueError as exc:
        raise MalformedURDFError(f"cannot parse the XML: {exc}", path=path, fix="save the model as UTF-8 XML") from None
    docinfo = root.getroottree().docinfo
    if docinfo.doctype or docinfo.internalDTD is not None or docinfo.externalDTD is not None:
        raise MalformedURDFError("the file declares a DOCTYPE; mer never resolves DTDs", path=path, line=1,
                                 fix="remove the DOCTYPE")  # fmt: skip
    if root.tag != "mujoco":
        hint = "this is a URDF: register it with --urdf" if root.tag == "robot" else "an MJCF's top element is <mujoco>"
        raise MalformedURDFError(f"the root element is <{root.tag}>, not <mujoco>", path=path, line=root.sourceline, fix=hint)
    _check_depth(root, str(path))
    return root


def _confine(target: Path, roots: tuple[Path, ...], *, what: str, path: Path, el: etree._Element) -> Path:
    """``target`` with links resolved, if it lies inside one of ``roots`` (resolved folders); else refused."""
    try:
        resolved = target.resolve()
    except (OSError, RuntimeError) as exc:
        raise MalformedURDFError(f"{what}: {target} cannot be resolved ({exc})", path=path, line=el.sourceline,
                                 element=f"<{el.tag}>", fix=_FIX_OUT) from None  # fmt: skip
    if not any(resolved == r or r in resolved.parents for r in roots):
        raise MalformedURDFError(f"{what} lies outside the model's folder ({resolved}); mer reads nothing outside it",
                                 path=path, line=el.sourceline, element=f"<{el.tag}>", fix=_FIX_OUT)  # fmt: skip
    return resolved


def _expand(root: etree._Element, path: Path, main_dir: Path, stack: tuple[Path, ...], budget: list[int],
            roots: tuple[Path, ...]) -> None:  # fmt: skip
    """Replace every ``<include file>`` under ``root`` by the children of the included ``<mujoco>``
    (MuJoCo's rule: file names relative to the main model's folder, which must hold them), recursively, in place."""
    for inc in list(root.iter("include")):
        name = inc.get("file")
        if not name:
            raise MalformedURDFError("<include> without file=", path=path, line=inc.sourceline, fix="name the file to include")
        target = Path(name) if Path(name).is_absolute() else main_dir / name
        resolved = _confine(target, roots, what=f"<include file={name!r}>", path=path, el=inc)
        if resolved in stack:
            raise MalformedURDFError(f"<include file={name!r}> includes itself (through {len(stack)} file(s))",
                                     path=path, line=inc.sourceline, fix="remove the circular <include>")  # fmt: skip
        if len(stack) > MAX_INCLUDE_DEPTH:
            raise MalformedURDFError(f"<include> nested deeper than {MAX_INCLUDE_DEPTH} files", path=path,
                                     line=inc.sourceline, fix="flatten the includes")  # fmt: skip
        if not target.exists():
            raise MalformedURDFError(f"<include file={name!r}>: {target} does not exist", path=path, line=inc.sourceline,
                                     fix=f"include files are found relative to the main model's folder ({main_dir})")  # fmt: skip
        sub = _read_xml(resolved, f"<include file={name!r}> (relative to the main model's folder {main_dir})", budget)
        _expand(sub, resolved, main_dir, (*stack, resolved), budget, roots)
        parent = inc.getparent()
        at = parent.index(inc)
        tail = inc.tail
        kids = [c for c in sub]
        parent[at : at + 1] = kids
        if kids:
            kids[-1].tail = (kids[-1].tail or "") + (tail or "")


def _check_files(root: etree._Element, path: Path, folder: Path, roots: tuple[Path, ...], assets: bool = True) -> None:
    """Every compile-time file of the (expanded) model inside ``roots``: the compiler's folders,
    and each file against the model's folder and against each of those folders (MuJoCo's bases).
    ``assets=False``: only the files read while MuJoCo parses (a flexcomp's), not the assets it compiles."""
    bases = [folder]
    for comp in root.iter("compiler"):
        for attr in _DIRS:
            d = comp.get(attr)
            if d:
                where = Path(d) if Path(d).is_absolute() else folder / d
                bases.append(_confine(where, roots, what=f"<compiler {attr}={d!r}>", path=path, el=comp) if assets else where)
    for el in root.iter(etree.Element):
        if el.tag in ("include", "model") or (not assets and el.tag != "flexcomp"):
            continue
        for attr in _FILE_ATTRS:
            name = el.get(attr)
            if name:
                for base in dict.fromkeys(bases):
                    _confine(Path(name) if Path(name).is_absolute() else base / name, roots,
                             what=f"<{el.tag} {attr}={name!r}>", path=path, el=el)  # fmt: skip


def _points(el: etree._Element, path: Path) -> int:
    """Points a ``<flexcomp>`` / ``<composite>`` makes (the product of its ``count``; 1 if none)."""
    text = el.get("count")
    if text is None:
        return 1
    n = 1
    for part in text.split():
        c = parse_count(part)
        if c is None:
            raise MalformedURDFError(f"<{el.tag} count={text[:60]!r}>: {part[:40]!r} is not a whole number", path=path,
                                     line=el.sourceline, element=f"<{el.tag}>", fix="write whole counts (e.g. 3 3 1)")  # fmt: skip
        n *= max(c, 1)
    return n


def count_expanded(root: etree._Element, path: Path, attached: dict[str, int] | None = None) -> int:
    """Elements the model makes once MuJoCo expands it: each element times the ``count`` of every
    ``<replicate>`` around it, plus the points of flexcomps and composites and the elements of
    attached sub-models. Refused past ``MER_MAX_MJCF_ELEMENTS``, at the element that crosses it."""
    cap = limit("MER_MAX_MJCF_ELEMENTS")
    total, mult = 0, [1]
    for event, el in etree.iterwalk(root, events=("start", "end")):
        if not isinstance(el.tag, str):
            continue
        if event == "end":
            mult.pop()
            continue
        m = mult[-1]
        if el.tag == "replicate":
            text = el.get("count", "1")
            c = parse_count(text)
            if c is None:
                raise MalformedURDFError(f"<replicate count={text[:40]!r}> is not a whole number", path=path,
                                         line=el.sourceline, element="<replicate>", fix="write count=N")  # fmt: skip
            mult.append(m * c)
        else:
            mult.append(m)
        total += m
        if el.tag in ("flexcomp", "composite"):
            total += m * _points(el, path) * (2 if el.tag == "composite" else 1)
        elif el.tag == "attach":
            total += m * (attached or {}).get(el.get("model", ""), 0)
        if total > cap:
            msg, fix = too_big("MER_MAX_MJCF_ELEMENTS", f"over {cap:,}")
            raise MalformedURDFError(f"{msg} (this element is made {m:,} times)", path=path,
                                     line=el.sourceline, element=f"<{el.tag}>", fix=fix)  # fmt: skip
    return total


def source_lines(root: etree._Element) -> dict[tuple[str, str], int]:
    """(tag, name) → line in the main file, for named bodies, joints and sites."""
    out: dict[tuple[str, str], int] = {}
    for tag in ("body", "joint", "freejoint", "site"):
        for el in root.iter(tag):
            name = el.get("name")
            if name and (tag, name) not in out:
                out["joint" if tag == "freejoint" else tag, name] = el.sourceline or 0
    return out


@dataclass
class ExpandedMjcf:
    """The main file's tree with includes expanded and files checked (``<model file>`` made absolute),
    the source lines of its own elements, and the sub-models it loads (element → (file, expanded tree))."""

    root: etree._Element
    lines: dict[tuple[str, str], int]
    models: list[tuple[etree._Element, Path, etree._Element]] = field(default_factory=list)


def expand_mjcf(path: Path, *, allowed: tuple[Path, ...] = (), assets: bool = True) -> ExpandedMjcf:
    """Read ``path`` and everything it includes, confined to its folder (and ``allowed`` folders),
    and count what it expands to (module docstring). ``assets=False``: the asset files (meshes,
    textures...) will not be read (kinematics only), so where they point is not checked; includes
    and sub-models always are. Raises :class:`MalformedURDFError`."""
    path = Path(path)
    folder = path.parent
    roots = tuple(dict.fromkeys(Path(r).resolve() for r in (folder, *allowed)))
    budget = [limit("MER_MAX_URDF_BYTES")]
    root = _read_xml(path, "MJCF given", budget)
    lines = source_lines(root)
    _expand(root, path, folder, (path.resolve(),), budget, roots)
    _check_depth(root, str(path))
    _check_files(root, path, folder, roots, assets)
    out = ExpandedMjcf(root, lines)
    attached: dict[str, int] = {}
    for el in root.iter("model"):
        name = el.get("file")
        if not name:
            continue
        target = Path(name) if Path(name).is_absolute() else folder / name
        resolved = _confine(target, roots, what=f"<model file={name!r}>", path=path, el=el)
        sub = _read_xml(resolved, f"<model file={name!r}> (relative to the model's folder {folder})", budget)
        _expand(sub, resolved, folder, (path.resolve(), resolved), budget, roots)
        _check_files(sub, resolved, resolved.parent, roots, assets)
        if next(sub.iter("model"), None) is not None:
            raise MalformedURDFError("a sub-model loads another <model>; mer reads one level of <asset><model>",
                                     path=resolved, line=next(sub.iter("model")).sourceline, element="<model>",
                                     fix="attach the models from the main file")  # fmt: skip
        attached[el.get("name") or resolved.stem] = count_expanded(sub, resolved)
        el.set("file", str(resolved))  # MuJoCo reads it against the working directory: give it the path found here
        out.models.append((el, resolved, sub))
    count_expanded(root, path, attached)
    return out


def expand_includes(path: str | Path) -> str:
    """The MJCF text of ``path`` with every ``<include>`` replaced by what it includes (numbers and
    comments verbatim): a single file. Raises :class:`MalformedURDFError`."""
    return etree.tostring(expand_mjcf(Path(path)).root, encoding="unicode")


def registry_copy(path: str | Path) -> tuple[str, dict[str, str]]:
    """What registration stores, self-contained: the expanded text (absolute compiler folders and
    file names made relative to the model's folder), and each ``<asset><model>`` file as a file of
    its own beside it (``model-K.xml``, its includes expanded), which the text names.

    Returns:
        (text, {file name: text}) for the registry's folder.
    """
    path = Path(path)
    e = expand_mjcf(path)
    folder = path.parent.resolve()
    extra: dict[str, str] = {}

    def relative(root: etree._Element) -> None:
        for el in root.iter(etree.Element):
            for attr in (*_FILE_ATTRS, *(_DIRS if el.tag == "compiler" else ())):
                v = el.get(attr)
                if v and Path(v).is_absolute():  # inside the folder (checked): the same place, relative
                    el.set(attr, os.path.relpath(Path(v).resolve(), folder) + (os.sep if v.endswith(("/", os.sep)) else ""))

    relative(e.root)
    for k, (el, _, sub) in enumerate(e.models):
        relative(sub)
        name = f"model-{k}.xml"
        el.set("file", name)
        extra[name] = etree.tostring(sub, encoding="unicode")
    return etree.tostring(e.root, encoding="unicode"), extra


def description_format(path: str | Path) -> Literal["urdf", "mjcf"]:
    """``mjcf`` when the file's root element is ``<mujoco>``, else ``urdf`` (also for files that are
    not XML at all: the URDF reader then says what is wrong). Reads the file (a regular file only)."""
    data = read_regular_file(Path(path), MalformedURDFError, "MER_MAX_URDF_BYTES", fix="check the path of the robot description")
    try:
        for _, el in etree.iterparse(io.BytesIO(data), events=("start",), resolve_entities=False, no_network=True,
                                     load_dtd=False, huge_tree=False):  # fmt: skip
            return "mjcf" if el.tag == "mujoco" else "urdf"
    except (etree.XMLSyntaxError, ValueError):
        pass
    return "urdf"
