"""Dataset cards for shard sets, rendered from the shards' own metadata (never from their data).

The card is a Hugging Face dataset card (YAML header + Markdown): licence (LAFAN1 is
CC BY-NC-ND 4.0), provenance (the source files with their sha256), counts, the configuration and
the command that rebuilds the set. The header is built and written by huggingface_hub's own
``DatasetCardData`` / ``DatasetCard`` (``license``, ``pretty_name``, ``task_categories: [robotics]``,
``tags``, ``configs``). For HDF5 sets it declares one ``datasets`` config per robot and split
(``g1_train``, ``g1_eval``...), so ``load_dataset(<folder or repo>, "g1_train")`` works.
"""

from __future__ import annotations

import json
from pathlib import Path

from mer_data.base.atomic import atomic_write
from mer_data.base.errors import ShardFormatError
from mer_data.base.outputs import refuse_foreign

from .humans import human_kind_of
from .reader import PathsLike, find_shards, open_shard
from .schema import FORMAT_NAME, FORMAT_VERSION, ShardMeta
from .sidecar import META_FILE

__all__ = ["render_card", "write_card", "refuse_foreign_outputs", "OWN_MARKS", "rebuild_command", "card_data", "LICENSE_ID", "TASK_CATEGORY"]

LICENSE_ID = "cc-by-nc-nd-4.0"
SYNTHETIC_LICENSE_ID = "apache-2.0"
TASK_CATEGORY = "robotics"
LAFAN1_TAGS = ["robotics", "motion-retargeting", "humanoid", "lafan1", "mer"]
SYNTHETIC_TAGS = ["robotics", "motion-retargeting", "humanoid", "synthetic", "mer"]
HUMAN_TAGS = ["robotics", "motion-retargeting", "humanoid", "human-motion", "mer"]
_DEFAULTS = {"format": "hdf5", "window": 60, "fps": 30.0, "split": "paper", "augment": 4, "seed": 0, "num_shards": 1}


def rebuild_command(cfg: dict, input_label: str | None = None, out: str = "OUT") -> str:
    """The ``mer shards build`` command line of a configuration."""
    if cfg.get("synthetic"):
        source = f"--synthetic {cfg['synthetic']} --synthetic-seconds {cfg['synthetic_seconds']:g} --synthetic-seed {cfg['synthetic_seed']}"
    else:
        source = f"--input {input_label or cfg['input']}"
    parts = ["mer shards build", source, f"--robots {' '.join(cfg['robots'])}", f"--out {out}"]
    for key, flag in (("format", "--format"), ("window", "--window"), ("fps", "--fps"), ("split", "--split"),
                      ("augment", "--augment"), ("seed", "--seed"), ("num_shards", "--num-shards")):  # fmt: skip
        if cfg.get(key) != _DEFAULTS[key]:
            parts.append(f"{flag} {cfg[key]:g}" if isinstance(cfg[key], float) else f"{flag} {cfg[key]}")
    if cfg.get("up"):
        parts.append(f"--up {cfg['up']}")
    if cfg.get("human_fps"):
        parts.append(f"--fps {cfg['human_fps']:g}")
    if cfg.get("body_model"):
        parts.append("--body-model MODELS")
    if cfg.get("stride") != cfg.get("window"):
        parts.append(f"--stride {cfg['stride']}")
    parts.append(f"--targets {' '.join(cfg['targets'])}")
    return " ".join(parts)


def card_data(*, license: str, pretty_name: str, tags: list[str], configs: list[dict] | None = None):
    """huggingface_hub's ``DatasetCardData`` of a shard set (the Hub keys of its card)."""
    from huggingface_hub import DatasetCardData

    return DatasetCardData(license=license, pretty_name=pretty_name, task_categories=[TASK_CATEGORY], tags=list(tags),
                           configs=configs or None)


def hub_card(data, body: str) -> str:
    """``---`` header ``---`` + body, written by huggingface_hub's ``DatasetCard`` (as ``push_to_hub`` writes it)."""
    from huggingface_hub import DatasetCard

    return str(DatasetCard(f"---\n{data.to_yaml()}\n---\n\n{body}"))


def _configs(metas: list[tuple[Path, ShardMeta, str]]) -> list[dict] | None:
    """One ``datasets`` config per robot and split of an HDF5 set: their rows differ in shape (nodes, samples)."""
    if metas[0][2] != "hdf5":
        return None
    out = []
    for r in sorted({m.robot for _, m, _ in metas}):
        for split in sorted({m.split for _, m, _ in metas if m.robot == r}, reverse=True):
            out.append({"config_name": f"{r}_{split}", "data_files": [{"split": split, "path": f"{r}-{split}-*.h5"}]})
    return out


def render_card(paths: PathsLike, *, input_label: str | None = None) -> str:
    """Markdown dataset card of the shards at ``paths`` (files or folders)."""
    shards = [(p, open_shard(p)) for p in find_shards(paths)]
    metas: list[tuple[Path, ShardMeta, str]] = [(p, s.meta, s.format) for p, s in shards]
    build_ids = {m.build_id for _, m, _ in metas}
    if len(build_ids) != 1:
        raise ShardFormatError(f"the shards come from {len(build_ids)} different builds; render one card per build")
    cfg = metas[0][1].config
    robots = ", ".join(sorted({m.robot for _, m, _ in metas}))
    body = render_lafan1_card(metas, cfg, input_label)
    if cfg.get("synthetic"):
        data = card_data(license=SYNTHETIC_LICENSE_ID, pretty_name=f"mer training shards: synthetic robot motion ({robots})",
                         tags=SYNTHETIC_TAGS, configs=_configs(metas))
        return hub_card(data, _synthetic_card(body, cfg))
    kinds = sorted({k for _, m, _ in metas if (k := human_kind_of(m.robot))})
    if kinds:
        data = card_data(license="other", pretty_name=f"mer training shards: human motion ({robots})", tags=HUMAN_TAGS,
                         configs=_configs(metas))
        return hub_card(data, _human_card(body, cfg, kinds[0]))
    data = card_data(license=LICENSE_ID, pretty_name=f"mer training shards: LAFAN1 robot motion ({robots})", tags=LAFAN1_TAGS,
                     configs=_configs(metas))
    return hub_card(data, body)


def _human_card(text: str, cfg: dict, kind: str) -> str:
    """The body of a build from human motion (``--robots bvh|smpl|joints``): its title, provenance and licence."""
    lafan1_provenance = text[text.index("Source: the LAFAN1") : text.index("Source files:") + len("Source files:")]
    lafan1_licence = text[text.index("CC BY-NC-ND 4.0 (") : text.index("## Loading")]
    what = {"bvh": "BVH motion capture", "smpl": "SMPL-family parameter files", "joints": "joint-position arrays"}[kind]
    return (
        text.replace("mer training shards: LAFAN1 robot motion", "mer training shards: human motion")
        .replace(lafan1_provenance, f"Source: {what} read by mer (`mer_data.motion.sources`), one reference skeleton per "
                 f"body among the clips (`{kind}`, `{kind}-2`, ...; docs/shards.md). Every window records its reference, clip, "
                 "start frame and the sha256 of its source file. Source files:")
        .replace(lafan1_licence, "The source files' own licence (`other`): motion capture and body-model data (AMASS, "
                 "Bandai-Namco, the SMPL family's models) usually forbid redistributing derivatives; check it before "
                 "sharing these shards.\n\n")
    )  # fmt: skip


def _synthetic_card(text: str, cfg: dict) -> str:
    """The body of a synthetic build's card: the LAFAN1 card's layout with its own title, provenance and licence."""
    lafan1_provenance = text[text.index("Source: the LAFAN1") : text.index("Source files:") + len("Source files:")]
    lafan1_licence = text[text.index("CC BY-NC-ND 4.0 (") : text.index("## Loading")]
    return (
        text.replace("mer training shards: LAFAN1 robot motion", "mer training shards: synthetic robot motion")
        .replace(
            lafan1_provenance,
            f"Source: synthetic motion generated by mer (`mer_data.synthesis`), {cfg['synthetic']} clip(s) of "
            f"{cfg['synthetic_seconds']:g} s per robot, seed {cfg['synthetic_seed']}; no motion capture data. Every window "
            "records its robot, clip, start frame and the sha256 of its generated motion. Clips:",
        )
        .replace(
            lafan1_licence,
            "Apache-2.0 (`apache-2.0`), like mer's code: the motion is generated by mer from the robot descriptions "
            "alone, no LAFAN1 or other motion data enters it. The robot descriptions keep their own licences.\n\n",
        )
    )


def render_lafan1_card(metas: list[tuple[Path, ShardMeta, str]], cfg: dict, input_label: str | None) -> str:
    """The card body, without the header (LAFAN1 wording; :func:`_synthetic_card` adapts it)."""
    fmt = metas[0][2]
    robots = sorted({m.robot for _, m, _ in metas})

    rows, sources = {}, []
    for p, m, _ in sorted(metas, key=lambda t: t[0].name):
        c = m.counts()
        key = (m.robot, m.split)
        t = rows.setdefault(key, {"files": 0, "clips": 0, "frames": 0, "windows": 0, "samples": 0, "bytes": 0})
        t["files"] += 1
        t["bytes"] += p.stat().st_size
        for k in ("clips", "frames", "windows", "samples"):
            t[k] += c[k]
        for s in m.sources:
            sources.append((m.robot, s["clip"], m.split, s.get("frames_in", 0), s.get("status"), s.get("sha256", "")))
    m0 = metas[0][1]
    aug = cfg["augmentation"]
    body = [
        f"# mer training shards: LAFAN1 robot motion ({', '.join(robots)})",
        "",
        f"Training and evaluation windows for the multi-embodiment retargeting model of **mer**, built by "
        f"`mer shards build` (mer {m0.mer_version}, format `{FORMAT_NAME}` v{FORMAT_VERSION}, {fmt.upper()}, "
        f"build id `{m0.build_id[:16]}`). This card was rendered from the shards' metadata.",
        "",
        "## Contents",
        "",
        "| robot | split | files | clips | frames | windows | samples | MB |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for (r, split), t in sorted(rows.items()):
        body.append(f"| {r} | {split} | {t['files']} | {t['clips']} | {t['frames']} | {t['windows']} | {t['samples']} | {t['bytes'] / 1e6:.1f} |")
    body += [
        "",
        f"Each window is {m0.window} frames at {m0.fps:g} Hz, origin-normalized (the first frame's base x, y at the "
        f"origin, height kept). Each window carries one sample per target robot ({', '.join(m0.targets)}); training "
        f"windows add {cfg['augment']} augmented target skeleton(s) per target (key links scaled "
        f"{aug['key_scale'][0]:g}-{aug['key_scale'][1]:g}, other links {aug['other_scale'][0]:g}-{aug['other_scale'][1]:g}, "
        f"non-end-effector correspondences dropped with probability {aug['drop_prob']:g}; seed {cfg['seed']}). "
        f"Split `{cfg['split']}`.",
        "",
        "## Provenance",
        "",
        "Source: the LAFAN1 Retargeting Dataset (Unitree's kinematic retargeting of Ubisoft La Forge's LAFAN1 motion "
        "capture onto its robots; Hugging Face `lvhaidong/LAFAN1_Retargeting_Dataset`). Every window records its robot, "
        "clip, start frame and the sha256 of its source file. Source files:",
        "",
        "| robot | clip | split | frames | status | sha256 |",
        "|---|---|---|---:|---|---|",
    ]
    for r, clip, split, frames, status, sha in sorted(sources):
        body.append(f"| {r} | {clip} | {split} | {frames} | {status} | `{sha}` |")
    shown = {k: v for k, v in cfg.items() if k not in ("resolved", "input", "body_model")}
    body += [
        "",
        "## How to rebuild",
        "",
        "```bash",
        rebuild_command(cfg, input_label),
        "```",
        "",
        "The same inputs (same sha256) and configuration give the same build id, the same augmentation draws "
        "and the same windows (bit for bit with the same mer and torch versions on the same kind of CPU; float32 "
        "forward kinematics may differ in the last bit elsewhere).",
        "",
        "## Configuration",
        "",
        "```json",
        json.dumps(shown, indent=1, sort_keys=True),
        "```",
        "",
        "## Licence",
        "",
        "CC BY-NC-ND 4.0 (`cc-by-nc-nd-4.0`), inherited from LAFAN1 (Ubisoft La Forge). Non-commercial research use "
        "only; no derivatives may be distributed. Do not publish these shards; share this card and the command above "
        "instead, so others rebuild them from the source.",
        "",
        "## Loading",
        "",
        "```python",
        "from torch.utils.data import DataLoader",
        "from mer_data.motion.samples import collate",
        "from mer_data.shards import ShardDataset",
        "",
        'train = ShardDataset("OUT", split="train")  # or "hf://datasets/OWNER/NAME[@REVISION]" once pushed',
        "loader = DataLoader(train, batch_size=16, shuffle=True, num_workers=4, collate_fn=collate)",
        "```",
        "",
        f"`mer shards push OUT OWNER/NAME` uploads the shards with this card and `{META_FILE}`, the shards' metadata "
        "as JSON (skeletons, target names, build configuration), which readers that ignore HDF5 attributes "
        "(`datasets.load_dataset`) need to resolve `sample_target` and the skeletons.",
        "",
    ]
    return "\n".join(body)


#: Text in every file of these names that mer writes into a shard folder: one without it is someone else's.
OWN_MARKS = {"README.md": "mer training shards", "mer_meta.json": '"mer-shards-meta"', "build-report*.json": '"build_id"'}


def refuse_foreign_outputs(out: str | Path, suffix: str = "") -> None:
    """Before a build writes into ``out``: its ``README.md``, ``mer_meta.json`` and build report, if
    present, must be mer's (:data:`OWN_MARKS`); a project's README under ``--out .`` is refused."""
    out = Path(out)
    for name, mark in OWN_MARKS.items():
        refuse_foreign(out / name.replace("*", suffix), mark, what=name.replace("*", suffix),
                       fix="choose a new or empty --out folder (mer writes README.md, mer_meta.json and build-report.json "
                           "there), or move the file away")  # fmt: skip


def write_card(out: str | Path, *, input_label: str | None = None, dest: str | Path | None = None) -> Path:
    """Render the card of the shards in folder ``out`` into ``dest`` (default ``out/README.md``), atomically.
    A ``dest`` that exists and is not a card mer wrote is refused (:class:`OutputPathError`), not replaced."""
    dest = Path(dest) if dest else Path(out) / "README.md"
    refuse_foreign(dest, OWN_MARKS["README.md"], what=dest.name,
                   fix="name another --out file, or move the file away")  # fmt: skip
    text = render_card(out, input_label=input_label)
    return atomic_write(dest, text)
