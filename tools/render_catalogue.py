"""Render the catalogue's planned (unpublished) model cards into cards/models and the packaged copy.

    PYTHONPATH=$PWD python tools/render_catalogue.py          # (re)write planned cards
    PYTHONPATH=$PWD python tools/render_catalogue.py --sync   # also copy every card to mer_models/cards

Published and bundled cards are never overwritten (they come from `mer zoo publish`). The repository's
cards/models is the source; mer_models/cards is its packaged copy (tests/models/hub/test_cards.py checks
they are identical).
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mer_models.hub.catalogue import render_catalogue  # noqa: E402
from mer_models.hub.registry import packaged_cards_dir  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sync", action="store_true", help="copy every card of cards/models into mer_models/cards")
    args = ap.parse_args()
    src = REPO / "cards" / "models"
    for path in render_catalogue(src):
        print(f"wrote {path.relative_to(REPO)}")
    if args.sync:
        dst = packaged_cards_dir()
        dst.mkdir(parents=True, exist_ok=True)
        for stale in dst.glob("*.md"):
            if not (src / stale.name).is_file():
                stale.unlink()
                print(f"removed {stale.relative_to(REPO)}")
        for card in sorted(src.glob("*.md")):
            shutil.copyfile(card, dst / card.name)
            print(f"copied {card.relative_to(REPO)} -> {(dst / card.name).relative_to(REPO)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
