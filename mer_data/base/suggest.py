"""“Did you mean …?” for names typed by hand (robots, models, options), by a distance that knows how
robot names are built: a vendor prefix (``unitree_g1`` is ``g1``), separators (``h1-2`` is ``h1_2``),
variants (``g1_29dof`` is a ``g1``), typos (``romoe`` is ``romeo``), and model numbers that are not
typos (``h2`` is not ``h1_2``: a robot of the same family, offered as such, never as the answer)."""

from __future__ import annotations

import difflib
import re
from typing import Iterable

__all__ = ["close_matches", "did_you_mean", "family_matches"]


_NEAR_BEST = 0.1  # names further than this below the best typo's ratio are not offered with it
# makers and collections whose name often leads a robot's (unitree_g1, limx_tron1, pal_talos, mjlab_unitree_g1)
VENDORS = frozenset({
    "unitree", "limx", "pal", "nasa", "bd", "bdai", "boston", "dynamics", "agility", "fourier", "ubtech", "apptronik",
    "booster", "engineai", "kepler", "pndbotics", "galaxea", "hightorque", "xiaomi", "aldebaran", "softbank", "iit",
    "anybotics", "mjlab", "gmr", "robot", "robots",
})  # fmt: skip
_SEP = re.compile(r"[\s_\-./]+")


def _tokens(name: str) -> list[str]:
    """Lower-case tokens of a name, leading dashes and vendor tokens dropped (``unitree_g1`` → ``["g1"]``)."""
    toks = [t for t in _SEP.split(name.lower().lstrip("-")) if t]
    core = [t for t in toks if t not in VENDORS]
    return core or toks


def _numbers(tokens: list[str]) -> list[str]:
    return re.findall(r"\d+", "".join(tokens))


def _family(tokens: list[str]) -> str | None:
    """The letters before the model number of a numbered name (``h1_2`` → ``h``), None without a number."""
    m = re.match(r"([a-z]+)\d", tokens[0]) if tokens else None
    return m.group(1) if m else None


def _is_variant(short: list[str], long: list[str]) -> bool:
    """``short`` names the same robot as ``long`` with fewer words: its tokens lead ``long``'s, the last one
    as a prefix (``tron1 wheel`` → ``tron1 wheelfoot``; ``tron`` → ``tron1``)."""
    if not short or len(short) > len(long) or short[:-1] != long[: len(short) - 1]:
        return False
    last, other = short[-1], long[len(short) - 1]
    return last == other or (len(last) >= 2 and other.startswith(last) and (len(short) < len(long) or other[len(last):].isdigit()
                                                                           or len(last) >= 3))  # fmt: skip


def _tiers(word: str, known: list[str]) -> tuple[list[str], list[str]]:
    """(the names ``word`` most likely means, best tier only; other models of its family)."""
    typed = _tokens(word)
    joined = "".join(typed)
    same, variant, typo, family = [], [], {}, []
    for name in known:
        toks = _tokens(name)
        if "".join(toks) == joined:  # case, separators, a vendor prefix
            same.append(name)
        elif _is_variant(typed, toks) or _is_variant(toks, typed):
            variant.append(name)
        elif _numbers(typed) == _numbers(toks):  # a model number is never a typo
            r = difflib.SequenceMatcher(None, joined, "".join(toks)).ratio()
            if r >= 0.6:
                typo[name] = r
        if name not in same and name not in variant and name not in typo and _family(typed) and _family(typed) == _family(toks):
            family.append(name)
    if same:
        return same, []
    if variant:
        typo = {n: difflib.SequenceMatcher(None, joined, "".join(_tokens(n))).ratio() for n in variant}
    if typo:  # the closest, and those about as close (a clear winner alone)
        best = max(typo.values())
        return sorted((n for n in typo if typo[n] >= best - _NEAR_BEST), key=lambda n: -typo[n]), []
    return [], family


def close_matches(word: str, choices: Iterable[str], n: int = 3) -> list[str]:
    """The known names ``word`` most likely means (case ignored), best first; at most ``n``.

    In order, the first kind that exists: the same name but for case, separators or a vendor prefix
    (``UNITREE-G1`` → ``g1``); a shorter or longer form of it (``g1_29dof`` → ``g1``, ``tron`` →
    ``tron1``); a typo with the same model numbers (``romoe`` → ``romeo``, ``mer-bse`` → ``mer-base``;
    by :class:`difflib.SequenceMatcher`, keeping those about as close as the best). ``h2`` matches
    none of ``h1``, ``h1_2``: see :func:`family_matches`. An exact name gives ``[]``.
    """
    known = list(dict.fromkeys(choices))
    if not isinstance(word, str) or not word or not known or word in known:
        return []
    lower = {c.lower(): c for c in known}
    if word.lower() in lower:
        return [lower[word.lower()]]
    return _tiers(word, known)[0][:n]


def family_matches(word: str, choices: Iterable[str], n: int = 3) -> list[str]:
    """Known robots of ``word``'s family with another model number (``h2`` → ``h1``, ``h1_2``), when no
    name is a likely match (:func:`close_matches`); ``[]`` otherwise."""
    known = list(dict.fromkeys(choices))
    if not isinstance(word, str) or not word or not known or word.lower() in {c.lower() for c in known}:
        return []
    return _tiers(word, known)[1][:n]


def _quoted(names: list[str], joint: str) -> str:
    q = [repr(m) for m in names]
    return q[0] if len(q) == 1 else ", ".join(q[:-1]) + f" {joint} " + q[-1]


def did_you_mean(word: str, choices: Iterable[str], n: int = 3) -> str:
    """``"did you mean 'romeo'?"`` for the likely names; for a name of a known family with an unknown model
    number, ``"nothing by that name; of the same family: 'h1' and 'h1_2' (other model numbers)"``; ``""`` when nothing is close."""
    choices = list(choices)
    found = close_matches(word, choices, n=n)
    if found:
        return f"did you mean {_quoted(found, 'or')}?"
    family = family_matches(word, choices, n=n)
    if family:
        return f"nothing by that name; of the same family: {_quoted(family, 'and')} (other model numbers)"
    return ""
