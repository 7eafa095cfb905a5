"""“Did you mean …?” for names typed by hand (robots, models): the closest known ones, by ``difflib``."""

from __future__ import annotations

import difflib
from typing import Iterable

__all__ = ["close_matches", "did_you_mean"]


_NEAR_BEST = 0.1  # names further than this below the best match's ratio are not offered with it


def close_matches(word: str, choices: Iterable[str], n: int = 3, cutoff: float = 0.6) -> list[str]:
    """The known names closest to ``word`` (case ignored), best first; at most ``n``, none below ``cutoff``.

    A name that differs only in case is the answer; otherwise :func:`difflib.get_close_matches`
    (the ratio of matching characters: ``romoe`` → ``romeo``, ``mer-bse`` → ``mer-base``), keeping
    only the names about as close as the best one (a clear winner is offered alone).
    """
    known = list(dict.fromkeys(choices))
    if not isinstance(word, str) or not word or not known:
        return []
    lower = {c.lower(): c for c in known}
    key = word.lower()
    if key in lower:
        return [] if lower[key] == word else [lower[key]]
    found = difflib.get_close_matches(key, list(lower), n=n, cutoff=cutoff)
    if not found:
        return []
    ratio = {m: difflib.SequenceMatcher(None, key, m).ratio() for m in found}
    best = max(ratio.values())
    return [lower[m] for m in found if ratio[m] >= best - _NEAR_BEST]


def did_you_mean(word: str, choices: Iterable[str], n: int = 3) -> str:
    """``"did you mean 'romeo'?"`` (or ``'a' or 'b'``) for the closest known names; ``""`` when none is close."""
    found = close_matches(word, choices, n=n)
    if not found:
        return ""
    quoted = [repr(m) for m in found]
    text = quoted[0] if len(quoted) == 1 else ", ".join(quoted[:-1]) + " or " + quoted[-1]
    return f"did you mean {text}?"
