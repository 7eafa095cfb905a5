"""A model card in a few lines: what the model is, what it is for, how accurate it is.

``mer zoo info NAME`` and ``mer demo`` print this; the whole card (training history, files,
checksums, licence note, how to reproduce) stays in the card file and ``mer zoo info --verbose``.

* **what it is**: the first sentence of the card's summary (cut at a word near 240 characters);
* **what it is for**: the robots it retargets from and to (and the model it was fine-tuned from);
* **headline accuracy**: E_g-mpbpe (the paper's main metric) per method, over every source and
  target robot the card's ``metrics`` record (``mer evaluate``), best method first: median and range;
  for a card without measurements, the figures the paper reports (``paper_metrics``), said to be so.
"""

from __future__ import annotations

import re
from statistics import median
from typing import Any, Iterator, Mapping

from .card import ModelCard

__all__ = ["brief_lines", "accuracy_lines", "first_sentence", "headline_accuracy"]

HEADLINE_METRIC = "E_g-mpbpe"  # the paper's main figure: body-part position error after scaling [m]
_SENTENCE_END = re.compile(r"(?<=[.!?])\s+(?=[A-Z`'\"(\[])")
_NUMBER = re.compile(r"^\s*([-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)")
_SOURCE_PREFIX = re.compile(r"^source (\S+), (.+)$")


def first_sentence(text: str, limit: int = 240) -> str:
    """The first sentence of ``text``, cut at a word boundary (with "…") when longer than ``limit``."""
    text = " ".join(str(text or "").split())
    head = _SENTENCE_END.split(text, maxsplit=1)[0]
    if len(head) <= limit:
        return head
    return head[:limit].rsplit(" ", 1)[0].rstrip(",;:") + " …"


def _number(v: Any) -> float | None:
    """A metric value as a float: numbers, and strings such as ``"0.0118"`` or ``"0.0071 ± 0.0038"`` (the mean)."""
    if isinstance(v, bool):
        return None
    if isinstance(v, (int, float)):
        return float(v)
    m = _NUMBER.match(str(v))
    return float(m.group(1)) if m else None


def _groups(metrics: Mapping[str, Any], path: tuple[str, ...] = ()) -> Iterator[tuple[tuple[str, ...], dict[str, float]]]:
    """(path, {robot: E_g-mpbpe}) for each mapping of robot → metrics that records the headline metric."""
    rows = {}
    for key, val in metrics.items():
        if not isinstance(val, Mapping):
            continue
        hit = next((v for k, v in val.items() if str(k).startswith(HEADLINE_METRIC)), None)
        x = _number(hit) if hit is not None else None
        if x is not None:
            rows[str(key)] = x
        else:
            yield from _groups(val, (*path, str(key)))
    if rows:
        yield path, rows


def _fmt(x: float) -> str:
    return f"{x:.2g}"


def headline_accuracy(metrics: Mapping[str, Any]) -> list[tuple[str, str]]:
    """(method, "median M m (A-B m, N source-target pairs)") per method, best median first.

    Groups named ``source X, METHOD`` are pooled over the sources; any other group is its own method.
    """
    pooled: dict[str, list[float]] = {}
    sources: dict[str, set[str]] = {}
    for path, rows in _groups(metrics):
        label = path[-1] if path else "all"
        m = _SOURCE_PREFIX.match(label)
        method = m.group(2) if m else label
        pooled.setdefault(method, []).extend(rows.values())
        if m:
            sources.setdefault(method, set()).add(m.group(1))
    out = []
    for method, xs in sorted(pooled.items(), key=lambda kv: median(kv[1])):
        what = "source-target pair" if method in sources else "robot"
        n = f"{len(xs)} {what}{'s' if len(xs) != 1 else ''}"
        span = f"{_fmt(min(xs))}-{_fmt(max(xs))} m, " if len(xs) > 1 else ""
        out.append((method, f"median {_fmt(median(xs))} m ({span}{n})"))
    return out


def _data_of(metrics: Mapping[str, Any]) -> str | None:
    for val in metrics.values():
        if isinstance(val, Mapping) and isinstance(val.get("data"), str):
            return " ".join(val["data"].split())
    return None


def accuracy_lines(card: ModelCard) -> list[str]:
    """``accuracy: ...`` and one indented line per method (mer's measurements, else the paper's figures)."""
    ours = headline_accuracy(card.metrics)
    if ours:
        data = _data_of(card.metrics)
        head = f"accuracy: {HEADLINE_METRIC}, lower is better" + (f"; {data}" if data else "") + ":"
    else:
        ours = headline_accuracy(card.paper_metrics)
        if not ours:
            return ["accuracy: not measured yet"]
        where = next(iter(card.paper_metrics), "the paper")
        head = f"accuracy: not measured by mer yet; {HEADLINE_METRIC} reported by the {where}, lower is better:"
    width = max(len(m) for m, _ in ours)
    return [head, *(f"  {m:{width}s}  {t}" for m, t in ours)]


def brief_lines(card: ModelCard) -> list[str]:
    """The card in a few lines (no indentation): what it is, its robots, its headline accuracy."""
    lines = [first_sentence(card.summary) or "(no summary)"]
    refs, targets = card.robots.get("references", []), card.robots.get("targets", [])
    if refs and list(refs) == list(targets):
        lines.append(f"robots:   {', '.join(targets)} (each as source and as target)")
    elif refs or targets:
        lines.append(f"robots:   from {', '.join(refs) or '?'} to {', '.join(targets) or '?'}")
    if card.base_model:
        lines.append(f"base:     fine-tuned from {card.base_model}")
    if card.repo_id and card.revision:
        lines.append(f"Hub:      {card.repo_id} @ {card.revision[:12]}")
    lines += accuracy_lines(card)
    if card.status == "unpublished":
        lines.append(f"weights:  not published yet (`mer zoo info {card.name} --verbose` shows how to train them)")
    return lines
