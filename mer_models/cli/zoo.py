"""``mer zoo list|info|download|publish``: thin wrappers over :mod:`mer_models.zoo`.

Only :mod:`argparse` is imported at module level (``mer --help`` stays fast); each command imports
what it uses.
"""

from __future__ import annotations

import argparse
import json


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``mer zoo`` and its sub-commands to ``sub``."""
    p = sub.add_parser("zoo", help="pretrained models: list, inspect, download, publish")
    zs = p.add_subparsers(dest="zoo_cmd", required=True, metavar="{list,info,download,publish}")

    q = zs.add_parser("list", help="the models mer knows, and where each is (bundled/cached/remote/not on Hub/unpublished)")
    q.add_argument("--json", action="store_true", help="machine-readable output")
    q.set_defaults(func=cmd_list)

    q = zs.add_parser("info", help="one model in a few lines: what it is, its robots, its accuracy (--verbose: the whole card)",
                      description="What the model is, the robots it retargets from and to, and its headline accuracy "
                      "(E_g-mpbpe per method). --verbose adds the training record, files and checksums, history, the "
                      "licence note and how to reproduce it; the card file has everything.")
    q.add_argument("name")
    q.add_argument("--json", action="store_true", help="print the card's metadata as JSON")
    q.add_argument("--verbose", action="store_true", dest="full",
                   help="the whole card: training record, files, earlier revisions, licence note, how to train it")
    q.set_defaults(func=cmd_info)

    q = zs.add_parser("download", help="fetch a model into the Hub cache and verify every file's sha256")
    q.add_argument("name", help="a zoo name (mer zoo list), or a Hub id ORG/NAME")
    q.add_argument("--revision", help="a commit (recommended) or branch; default: the card's pinned commit")
    q.set_defaults(func=cmd_download)

    q = zs.add_parser("publish", help="upload a checkpoint to the Hub and record commit and checksums in its card")
    q.add_argument("checkpoint", help="checkpoint folder (config.json + model.safetensors)")
    q.add_argument("--name", required=True, help="zoo name, e.g. mer-base-talos")
    q.add_argument("--repo-id", required=True, help="Hub repository ORG/NAME (created if missing)")
    q.add_argument("--base", help="zoo name of the model it was fine-tuned from")
    q.add_argument("--license", help="licence of the weights when the training data is not a known dataset")
    q.add_argument("--summary", help="one-line description (default: from the checkpoint)")
    q.add_argument("--cards-dir", help="where to write the card (default: cards/models for a catalogue name in a "
                   "source checkout, else $MER_HOME/cards/models)")
    q.add_argument("--private", action="store_true", help="create the repository as private")
    q.set_defaults(func=cmd_publish)


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB" if n else "-"


def cmd_list(args: argparse.Namespace) -> int:
    """``mer zoo list``: every model mer knows and where it is."""
    from mer_models.hub import resolve as api
    from mer_models.hub.registry import Registry

    reg = Registry()
    rows = []
    for e in api.list_models(reg):
        c = e.card
        rows.append({"name": c.name, "where": api.where(e, reg), "status": c.status, "source": e.source,
                     "size": c.size, "targets": c.robots.get("targets", []), "references": c.robots.get("references", []),
                     "repo_id": c.repo_id, "revision": c.revision, "base_model": c.base_model, "license": c.license})
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print(f"{'name':20s} {'where':12s} {'size':>9s}  {'licence':16s} target robots")
    for r in rows:
        print(f"{r['name']:20s} {r['where']:12s} {_mb(r['size']):>9s}  {r['license']:16s} {', '.join(r['targets'])}")
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    """``mer zoo info NAME``: a few lines by default (:func:`~mer_models.hub.brief.brief_lines`); the whole card with --verbose."""
    from mer_models.hub import resolve as api
    from mer_models.hub.brief import accuracy_lines, brief_lines
    from mer_models.hub.registry import Registry

    reg = Registry()
    e = api.model_info(args.name, reg)
    c = e.card
    if args.json:
        print(json.dumps({"where": api.where(e, reg), "source": e.source, "card": str(c.path), **c.to_meta(),
                          "license": c.license}, indent=2))
        return 0
    print(f"{c.name}  ({api.where(e, reg)}, {c.license})")
    if not args.full:
        for line in brief_lines(c):
            print(f"  {line}")
        print(f"  card:     {c.path} (all of it: `mer zoo info {c.name} --verbose`)")
        return 0
    print(f"  {e.source} card {c.path}")
    print(f"  {c.summary}")
    for line in accuracy_lines(c):
        print(f"  {line}")
    if c.repo_id:
        print(f"  repo:      {c.repo_id} @ {c.revision or 'not published yet'}")
    if c.base_model:
        print(f"  base:      {c.base_model} @ {c.base_revision or '-'}")
    print(f"  targets:   {', '.join(c.robots.get('targets', [])) or '-'}")
    print(f"  refs:      {', '.join(c.robots.get('references', [])) or '-'}")
    for k, v in c.training.items():
        print(f"  {k + ':':10s} {', '.join(map(str, v)) if isinstance(v, list) else v}")
    for fname, rec in c.files.items():
        print(f"  file:      {fname}  {rec.size} bytes  sha256 {rec.sha256}")
    for h in c.history:
        print(f"  earlier:   {h.revision} ({h.published or '?'})")
    print(f"  licence:   {c.license}. {c.license_note}")
    if c.status == "unpublished":
        print("  The weights are not yet published. To train them:")
        for line in c.reproduce.splitlines():
            print(f"    {line}")
    return 0


def cmd_download(args: argparse.Namespace) -> int:
    """``mer zoo download NAME``: fetch into the Hub cache and verify."""
    from mer_models.hub import resolve as api

    res = api.resolve(args.name, args.revision)
    how = {"card": "size and sha256 checked against the card", "hub": "checked against the Hub's content ids (no card)",
           "none": "local folder, not checked"}[res.verified]
    at = f"{res.repo_id}@{res.revision}" if res.repo_id else res.source
    print(f"{args.name}: {at} -> {res.folder} ({how})")
    return 0


def cmd_publish(args: argparse.Namespace) -> int:
    """``mer zoo publish``: upload a checkpoint and record it in its card."""
    from mer_models.hub.publish import publish

    r = publish(args.checkpoint, name=args.name, repo_id=args.repo_id, base=args.base, cards_dir=args.cards_dir,
                license=args.license, summary=args.summary, private=args.private)
    print(f"published {r.card.name} as {r.card.repo_id}@{r.commit}")
    for fname, rec in r.card.files.items():
        print(f"  {fname}  {rec.size} bytes  sha256 {rec.sha256}")
    print(f"card: {r.card_path}")
    return 0
