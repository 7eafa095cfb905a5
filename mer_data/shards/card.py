"""Dataset cards for shard sets, rendered from the shards' own metadata (never from their data).

The card is a Hugging Face dataset card (YAML header + Markdown): licence (LAFAN1 is
CC BY-NC-ND 4.0), provenance (the source files with their sha256), counts, the configuration and
the command that rebuilds the set. For HDF5 sets the header declares one ``datasets`` config per
robot and split (``g1_train``, ``g1_eval``...), so ``load_dataset(<folder or repo>, "g1_train")`` works.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..atomic import atomic_write
from ..errors import ShardFormatError
from .reader import PathsLike, find_shards, open_shard
from .schema import FORMAT_NAME, FORMAT_VERSION, ShardMeta

__all__ = ["render_card", "write_card", "rebuild_command", "LICENSE_ID"]

LICENSE_ID = "cc-by-nc-nd-4.0"
_DEFAULTS = {"format": "hdf5", "window": 60, "fps": 30.0, "split": "paper", "augment": 4, "seed": 0, "num_shards": 1}


def rebuild_command(cfg: dict, input_label: str | None = None, out: str = "OUT") -> str:
    """The ``mer shards build`` command line of a configuration."""
    parts = ["mer shards build", f"--input {input_label or cfg['input']}", f"--robots {' '.join(cfg['robots'])}", f"--out {out}"]
    for key, flag in (("format", "--format"), ("window", "--window"), ("fps", "--fps"), ("split", "--split"),
                      ("augment", "--augment"), ("seed", "--seed"), ("num_shards", "--num-shards")):  # fmt: skip
        if cfg.get(key) != _DEFAULTS[key]:
            parts.append(f"{flag} {cfg[key]:g}" if isinstance(cfg[key], float) else f"{flag} {cfg[key]}")
    if cfg.get("stride") != cfg.get("window"):
        parts.append(f"--stride {cfg['stride']}")
    parts.append(f"--targets {' '.join(cfg['targets'])}")
    return " ".join(parts)


def render_card(paths: PathsLike, *, input_label: str | None = None) -> str:
    """Markdown dataset card of the shards at ``paths`` (files or folders)."""
    shards = [(p, open_shard(p)) for p in find_shards(paths)]
    metas: list[tuple[Path, ShardMeta, str]] = [(p, s.meta, s.format) for p, s in shards]
    build_ids = {m.build_id for _, m, _ in metas}
    if len(build_ids) != 1:
        raise ShardFormatError(f"the shards come from {len(build_ids)} different builds; render one card per build")
    cfg = metas[0][1].config
    fmt = metas[0][2]
    robots = sorted({m.robot for _, m, _ in metas})
    ext = ".h5" if fmt == "hdf5" else ".mcap"
    header = [
        "---",
        f"license: {LICENSE_ID}",
        f'pretty_name: "mer training shards: LAFAN1 robot motion ({", ".join(robots)})"',
        "tags: [robotics, motion-retargeting, humanoid, lafan1, mer]",
    ]
    if fmt == "hdf5":  # one config per robot and split: their rows differ in shape (nodes, samples per window)
        header.append("configs:")
        for r in robots:
            for split in sorted({m.split for _, m, _ in metas if m.robot == r}, reverse=True):
                header += [f"- config_name: {r}_{split}", "  data_files:", f"  - split: {split}", f'    path: "{r}-{split}-*{ext}"']
    header.append("---")

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
    shown = {k: v for k, v in cfg.items() if k not in ("resolved", "input")}
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
        "from mer_data.samples import collate",
        "from mer_data.shards import ShardDataset",
        "",
        'train = ShardDataset("OUT", split="train")',
        "loader = DataLoader(train, batch_size=16, shuffle=True, num_workers=4, collate_fn=collate)",
        "```",
        "",
    ]
    return "\n".join(header + [""] + body)


def write_card(out: str | Path, *, input_label: str | None = None, dest: str | Path | None = None) -> Path:
    """Render the card of the shards in folder ``out`` into ``dest`` (default ``out/README.md``), atomically."""
    dest = Path(dest) if dest else Path(out) / "README.md"
    text = render_card(out, input_label=input_label)
    return atomic_write(dest, text)
