"""Render a :class:`~.card.ModelCard` to its ``README.md`` text (YAML front matter + markdown body).

The front matter is built and written by huggingface_hub's own card classes (``ModelCardData``,
``ModelCard``), so it carries the Hub's keys in the Hub's layout: ``base_model`` (a repo id, for
fine-tunes), ``datasets`` (Hub dataset ids of the training data), ``library_name: mer``,
``license``, ``pipeline_tag: robotics``, ``tags``, then mer's own ``mer:`` block.

The body comes from the shipped template ``mer_models/templates/model_card.md``; every section is
computed from the card's metadata, so ``render_card(parse_card(text)) == text`` for every card mer
wrote (tests check this for the whole catalogue: a hand edit shows up as a difference).
"""

from __future__ import annotations

import string
from importlib import resources
from typing import Any, Mapping

from .card import ModelCard
from .fromckpt import DATASETS

__all__ = ["render_card", "card_data", "front_matter", "TAGS", "PIPELINE_TAG", "LIBRARY_NAME"]

TAGS = ["robotics", "motion-retargeting", "diffusion", "humanoid", "mer"]
PIPELINE_TAG = "robotics"  # the Hub's task for robot policies and motion models (as LeRobot's cards)
LIBRARY_NAME = "mer"


def _template() -> string.Template:
    text = resources.files("mer_models").joinpath("templates/model_card.md").read_text(encoding="utf-8")
    return string.Template(text)


def hub_datasets(card: ModelCard) -> list[str]:
    """Hub dataset ids of the card's training data (empty for data that is not on the Hub)."""
    known = DATASETS.get(str(card.training.get("dataset")))
    return [known.hub_id] if known is not None and known.hub_id else []


def card_data(card: ModelCard):
    """The card's metadata as huggingface_hub's ``ModelCardData`` (Hub keys + the ``mer:`` block)."""
    from huggingface_hub import ModelCardData

    return ModelCardData(
        base_model=card.base_repo_id or None,  # the Hub's convention: the base's repo id, top level
        datasets=hub_datasets(card) or None,
        library_name=LIBRARY_NAME,
        license=card.license,
        pipeline_tag=PIPELINE_TAG,
        tags=[("warm-start" if t == "diffusion" and card.checkpoint.get("kind") == "warm" else t) for t in TAGS],
        mer=card.to_meta(),
    )


def front_matter(card: ModelCard) -> dict[str, Any]:
    """The YAML mapping: Hub keys first, then the ``mer:`` block (``None`` values left out)."""
    return card_data(card).to_dict()


def _num(v: Any) -> str:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return str(v)
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _table(rows: Mapping[str, Any], first: str) -> str:
    """Mapping row -> (mapping column -> scalar) as a markdown table; scalars as a 2-column table."""
    if all(isinstance(v, Mapping) for v in rows.values()):
        cols: list[str] = []
        for v in rows.values():
            cols += [c for c in v if c not in cols]
        lines = ["| " + " | ".join([first, *cols]) + " |", "|" + "---|" * (len(cols) + 1)]
        for r, v in rows.items():
            lines.append("| " + " | ".join([str(r), *(_num(v.get(c, "")) for c in cols)]) + " |")
        return "\n".join(lines)
    lines = [f"| {first} | value |", "|---|---|"]
    lines += [f"| {k} | {_num(v)} |" for k, v in rows.items()]
    return "\n".join(lines)


def _metrics_section(metrics: Mapping[str, Any], empty: str) -> str:
    if not metrics:
        return empty
    parts = []
    for key, val in metrics.items():
        if isinstance(val, Mapping) and val:
            scalars = {k: v for k, v in val.items() if not isinstance(v, Mapping)}
            nested = {k: v for k, v in val.items() if isinstance(v, Mapping)}
            parts.append(f"**{key}**")
            if scalars:
                parts.append(_table(scalars, "metric"))
            for sub, rows in nested.items():
                if rows and all(isinstance(v, Mapping) for v in rows.values()):
                    parts.append(f"*{sub}*\n\n" + _table(rows, "robot"))
                elif rows:
                    parts.append(f"*{sub}*\n\n" + _table(rows, "metric"))
        else:
            parts.append(f"**{key}**: {_num(val)}")
    return "\n\n".join(parts)


def _banner(card: ModelCard) -> str:
    if card.status == "unpublished":
        return (
            "> **Weights not yet published.** This card describes a planned model: "
            f"`mer zoo download {card.name}` and `load(\"{card.name}\")` refuse with this message. "
            "Train it yourself with the command under *Reproduce*, or use the bundled default model."
        )
    if card.status == "bundled":
        where = f" Also on the Hub as `{card.repo_id}` at `{card.revision}`." if card.repo_id and card.revision else ""
        return (
            f"> **Bundled with the package** in `mer_models/bundled/{card.name}/`: it loads offline, with no "
            f"download, and every file is checked against the sha256 below.{where}"
        )
    return (
        f"> Published on the Hub as [`{card.repo_id}`](https://huggingface.co/{card.repo_id}), pinned to revision "
        f"`{card.revision}`; every file is checked against the sha256 below before it is used."
    )


def _usage(card: ModelCard) -> str:
    lines = ["```bash"]
    if card.status == "published":
        lines.append(f"mer zoo download {card.name}")
    lines += [f"mer zoo info {card.name}", "```", "", "```python", "from mer_models import zoo", "",
              f'ckpt = zoo.load("{card.name}")  # model built from config.json, weights loaded strictly', "",
              *(["from mer_models.warm import WarmModel", "", f'model = WarmModel.from_pretrained("{card.name}")  # the same, as an nn.Module']
                if card.checkpoint.get("kind") == "warm" else
                ["from mer_models import RetargetModel", "", f'model = RetargetModel.from_pretrained("{card.name}")  # the same, as an nn.Module']),
              "```"]  # fmt: skip
    return "\n".join(lines)


def _robots(card: ModelCard) -> str:
    t = ", ".join(card.robots.get("targets", [])) or "none recorded"
    r = ", ".join(card.robots.get("references", [])) or "none recorded"
    text = f"- Target robots (it retargets *to*): {t}\n- Reference robots (it retargets *from*): {r}"
    if card.base_model:
        rev = f" at `{card.base_revision}`" if card.base_revision else ""
        text += f"\n- Fine-tuned from `{card.base_model}`{rev} by adding new target skeletons (`mer finetune`)."
    return text


def _training(card: ModelCard) -> str:
    if not card.training:
        return "Not recorded."
    return _table({k: (", ".join(map(str, v)) if isinstance(v, list) else v) for k, v in card.training.items()}, "field")


def _files(card: ModelCard) -> str:
    if not card.files:
        return "No files yet: the weights are not published."
    lines = ["| file | size [bytes] | sha256 |", "|---|---|---|"]
    lines += [f"| {n} | {f.size} | `{f.sha256}` |" for n, f in card.files.items()]
    if card.history:
        lines += ["", "Earlier revisions, still loadable with `revision=` and still verified:", ""]
        lines += [f"- `{h.revision}` ({h.published or 'date not recorded'})" for h in card.history]
    return "\n".join(lines)


def _licence(card: ModelCard) -> str:
    text = f"`{card.license}`."
    return f"{text} {card.license_note}" if card.license_note else text


def _metrics(card: ModelCard) -> str:
    ours = _metrics_section(card.metrics, "Not measured yet (`mer evaluate` fills this table when the weights exist).")
    if card.paper_metrics:
        ours += "\n\nFor reference, the figures the paper *reports* for this configuration (not measured by mer):\n\n"
        ours += _metrics_section(card.paper_metrics, "")
    return ours


def render_card(card: ModelCard) -> str:
    """The card's full text: ``---`` YAML ``---`` then the template filled from the metadata."""
    from huggingface_hub import ModelCard as HubModelCard

    body = _template().substitute(
        title=card.name,
        banner=_banner(card),
        summary=card.summary or "",
        usage=_usage(card),
        robots=_robots(card),
        training=_training(card),
        metrics=_metrics(card),
        files=_files(card),
        licence=_licence(card),
        reproduce=f"```bash\n{card.reproduce}\n```" if card.reproduce else "Not recorded.",
    )
    hub_card = HubModelCard(f"---\n{card_data(card).to_yaml()}\n---\n{body}")
    return str(hub_card)  # huggingface_hub writes the front matter (as ``ModelCard.save`` / ``push_to_hub`` do)
