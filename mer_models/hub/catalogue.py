"""The catalogue: the models mer plans to publish, and their cards before the weights exist.

A planned model's card is rendered from the specification below (status ``unpublished``): it says
plainly that the weights are not yet published and how to train them. When the weights are
trained and published (``mer zoo publish``), the card is re-rendered from the checkpoint's own
metadata and :func:`render_catalogue` never overwrites it with the planned one again.

``tools/render_catalogue.py`` (re)writes the planned cards into ``cards/models`` and the packaged
copy; a test checks the committed cards equal what this module renders.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .card import ModelCard, read_card
from .fromckpt import DATASETS
from .registry import write_card

__all__ = ["PlannedModel", "CATALOGUE", "planned_card", "render_catalogue", "PAPER_METRICS"]

_LAFAN = "LAFAN1 robot CSVs (G1 and H1, 40 clips each; retargeted from Ubisoft La Forge's LAFAN1)"
_SPLIT = ("paper: 3 clips per robot of the types dance, fallAndGetUp and fight are trained on; "
          "every other clip is held out as unseen motion")
_COLS = ("E_g-mpbpe [m]", "E_mpboe [rad]", "E_mpbve [m/s]", "E_smooth [rad/s^3]")


def _row(*vals: str) -> dict[str, str]:
    return dict(zip(_COLS, vals))


# Table II of the paper (mean ± std), for reference on the cards; never presented as mer's own figures.
PAPER_METRICS: dict[str, dict[str, dict[str, str]]] = {
    "in-domain": {
        "g1": _row("0.0071 ± 0.0038", "0.30 ± 0.19", "0.0075 ± 0.0035", "0.023 ± 0.0073"),
        "h1": _row("0.012 ± 0.0059", "0.22 ± 0.16", "0.013 ± 0.0057", "0.024 ± 0.0083"),
        "oli": _row("0.011 ± 0.0052", "0.25 ± 0.17", "0.013 ± 0.0052", "0.023 ± 0.0084"),
        "atlas": _row("0.016 ± 0.0059", "0.30 ± 0.20", "0.021 ± 0.0061", "0.029 ± 0.0084"),
        "tron1": _row("0.015 ± 0.0054", "0.57 ± 0.27", "0.029 ± 0.0088", "0.020 ± 0.0089"),
        "talos": _row("0.014 ± 0.0073", "0.21 ± 0.17", "0.015 ± 0.0068", "0.022 ± 0.0087"),
        "valkyrie": _row("0.015 ± 0.0073", "0.24 ± 0.18", "0.014 ± 0.0050", "0.024 ± 0.0097"),
    },
    "out-of-domain": {
        "g1": _row("0.020 ± 0.033", "0.29 ± 0.13", "0.019 ± 0.028", "0.019 ± 0.0064"),
        "h1": _row("0.20 ± 0.68", "0.33 ± 0.48", "0.17 ± 0.56", "0.022 ± 0.0071"),
        "oli": _row("0.12 ± 0.39", "0.32 ± 0.35", "0.12 ± 0.40", "0.020 ± 0.0073"),
        "atlas": _row("0.65 ± 2.02", "0.47 ± 0.75", "0.59 ± 1.82", "0.027 ± 0.011"),
        "tron1": _row("0.026 ± 0.024", "0.73 ± 0.16", "0.041 ± 0.026", "0.017 ± 0.0081"),
    },
}

BASE_TARGETS = ("g1", "h1", "atlas", "oli", "tron1")


@dataclass(frozen=True)
class PlannedModel:
    """A catalogue entry before its weights exist."""

    name: str
    repo_id: str
    summary: str
    targets: tuple[str, ...]
    references: tuple[str, ...]
    training: dict[str, Any]
    reproduce: str
    base: str | None = None
    metric_robots: tuple[str, ...] = field(default_factory=tuple)

    def paper_metrics(self) -> dict[str, Any]:
        out = {}
        for domain, rows in PAPER_METRICS.items():
            sel = {r: v for r, v in rows.items() if r in self.metric_robots}
            if sel:
                out[domain] = sel
        return {"paper, Table II": out} if out else {}


def _base_reproduce() -> str:
    return "\n".join([
        "mer shards build --input LAFAN1_DIR --robots g1 h1 --split paper --targets " + " ".join(BASE_TARGETS) + " --out shards/lafan1",
        "mer train --config paper --shards shards/lafan1 --out runs/mer-paper --steps STEPS --device cuda",
        "mer evaluate --model runs/mer-paper --input LAFAN1_DIR --targets " + " ".join(BASE_TARGETS) + " --save runs/mer-paper/metrics.json",
        "mer zoo publish runs/mer-paper --name mer-paper --repo-id ORG/mer-paper",
    ])


def _finetune_reproduce(robot: str) -> str:
    name = f"mer-paper-{robot}"
    return "\n".join([
        f"mer finetune --base mer-paper --robot {robot} --shards shards/lafan1 --out runs/{name} --steps STEPS --device cuda",
        f"mer evaluate --model runs/{name} --input LAFAN1_DIR --targets {robot} --save runs/{name}/metrics.json",
        f"mer zoo publish runs/{name} --name {name} --repo-id ORG/{name} --base mer-paper",
    ])


def _training(targets: tuple[str, ...], extra: dict[str, Any] | None = None) -> dict[str, Any]:
    return {"dataset": "lafan1", "config": "paper", "source": _LAFAN, "reference_robots": ["g1", "h1"],
            "target_robots": list(targets), "split": _SPLIT, "frames": "60-frame windows at 30 Hz", **(extra or {})}


CATALOGUE: tuple[PlannedModel, ...] = (
    PlannedModel(
        name="mer-paper",
        repo_id="mer-robotics/mer-paper",
        summary="The paper's configuration (H = 240, 4 layers per decoder, 6 heads) trained on G1 and H1 LAFAN1 "
        "motion, retargeting to G1, H1, Atlas, Oli and Tron1.",
        targets=BASE_TARGETS,
        references=("g1", "h1"),
        training=_training(BASE_TARGETS),
        reproduce=_base_reproduce(),
        metric_robots=BASE_TARGETS,
    ),
    *(
        PlannedModel(
            name=f"mer-paper-{robot}",
            repo_id=f"mer-robotics/mer-paper-{robot}",
            summary=f"`mer-paper` fine-tuned for {robot.capitalize()}, a robot the base model never saw: its skeleton is "
            "added to the training targets and training continues from the base weights (paper, unseen embodiments).",
            targets=(*BASE_TARGETS, robot),
            references=("g1", "h1"),
            training=_training((*BASE_TARGETS, robot), {"fine_tuned_for": robot}),
            reproduce=_finetune_reproduce(robot),
            base="mer-paper",
            metric_robots=(robot,),
        )
        for robot in ("talos", "valkyrie")
    ),
)


def planned_card(p: PlannedModel) -> ModelCard:
    """The ``unpublished`` card of a catalogue entry."""
    lic = DATASETS["lafan1"]
    base_repo = next((b.repo_id for b in CATALOGUE if b.name == p.base), None) if p.base else None
    return ModelCard(
        name=p.name, status="unpublished", summary=p.summary, license=lic.license, repo_id=p.repo_id,
        base_model=p.base, base_repo_id=base_repo, robots={"targets": list(p.targets), "references": list(p.references)},
        training=dict(p.training), paper_metrics=p.paper_metrics(),
        checkpoint={"format": "mer-checkpoint", "config": "paper"},
        license_note=lic.note + " The planned Hub repository does not exist until the weights are published.",
        reproduce=p.reproduce,
    )


def render_catalogue(folder: str | Path) -> list[Path]:
    """Write the planned cards into ``folder``, leaving any card that is already published or bundled."""
    written = []
    for p in CATALOGUE:
        path = Path(folder) / f"{p.name}.md"
        if path.is_file() and read_card(path).status != "unpublished":
            continue
        written.append(write_card(planned_card(p), Path(folder)))
    return written
