"""The catalogue's fine-tuned warm start (``mer-warm-romeo``, ``tools/finetune_warm.py``): its card pins the
weights committed in ``cards/weights/``; published to a fresh loopback Hub (tests/hub_server.py) they get
exactly the pinned commit, and the model then loads BY NAME through the repository's own catalogue, and,
once cached, retargets to Romeo with the network off.

Clients run in fresh interpreters with HF_* set before huggingface_hub is imported (tests/zoo_worker.py).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hub_server import HubServer
from zoo_helpers import TOKEN, client_env
from zoo_worker import run_worker

from mer_models.hub.card import read_card
from mer_models.hub.integrity import sha256_file
from mer_models.hub.names import is_commit
from mer_models.hub.registry import packaged_cards_dir
from mer_models.hub.render import render_card

REPO = Path(__file__).resolve().parents[3]
NAME = "mer-warm-romeo"
CARD = REPO / "cards" / "models" / f"{NAME}.md"
WEIGHTS = REPO / "cards" / "weights" / NAME

# publish() as `mer zoo publish` runs it for a catalogue name, into a copy of the catalogue without the card
_PUBLISH = """
import json, sys
from mer_models.hub.publish import publish
from mer_models.hub.registry import Registry
a = json.loads(sys.argv[1])
r = publish(a["folder"], name=a["name"], repo_id=a["repo_id"], base=a["base"], summary=a["summary"],
            cards_dir=a["catalogue"], registry=Registry(builtin=a["catalogue"]))
print(json.dumps({"commit": r.commit}))
"""


def _env(env: dict[str, str]) -> dict[str, str]:
    base = {k: v for k, v in os.environ.items() if not k.startswith(("HF_", "HUGGINGFACE_"))}
    return {**base, **env, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}


def test_the_card_pins_the_committed_synthetic_weights():
    card = read_card(CARD)
    assert (packaged_cards_dir() / CARD.name).read_bytes() == CARD.read_bytes()
    assert card.status == "published" and card.repo_id == f"mer-robotics/{NAME}" and is_commit(card.revision)
    assert sorted(card.files) == ["config.json", "model.safetensors"]
    for fname, rec in card.files.items():
        assert rec.sha256 == sha256_file(WEIGHTS / fname) and rec.size == (WEIGHTS / fname).stat().st_size
    assert card.size < 1_000_000  # small enough to live in the repository
    meta = json.loads((WEIGHTS / "config.json").read_text())
    assert meta["run"]["kind"] == "warm" and meta["data"]["finetune_robot"] == "romeo"
    assert "romeo" in card.targets and {"g1", "h1"} <= set(card.targets) and card.robots["references"]
    # synthetic motion only: the package's licence, and no LAFAN1 and no local path in what is published
    assert card.license == "apache-2.0" and card.training["dataset"] == "synthetic"
    text = json.dumps(meta["data"])
    assert "lafan" not in text.lower() and "/tmp/" not in text and "/work/" not in text
    # the gain is measured: base (zero-shot) and fine-tuned on LAFAN1 G1 windows, and the optimiser
    ev = card.metrics["evaluation (mer evaluate)"]
    assert {"source g1, base + 2 LM iterations", "source g1, fine-tuned + 2 LM iterations", "source g1, optimiser"} <= set(ev)
    assert "tools/finetune_warm.py" in card.reproduce and "--publish" in card.reproduce


@pytest.fixture(scope="module")
def published(tmp_path_factory):
    """A fresh loopback Hub holding the committed weights, published as the maintainer publishes them."""
    tmp = tmp_path_factory.mktemp("warm_zoo")
    card = read_card(CARD)
    catalogue = tmp / "catalogue"
    shutil.copytree(REPO / "cards" / "models", catalogue)
    (catalogue / CARD.name).unlink()
    home = tmp / "mer_home"
    with HubServer(token=TOKEN) as hub:
        env = client_env(hub.url, tmp / "publisher", home)
        a = {"folder": str(WEIGHTS), "name": NAME, "repo_id": card.repo_id, "base": card.base_model, "summary": card.summary,
             "catalogue": str(catalogue)}  # fmt: skip
        r = subprocess.run([sys.executable, "-c", _PUBLISH, json.dumps(a)], env=_env(env), capture_output=True, text=True,
                           timeout=120, cwd=str(REPO))  # fmt: skip
        assert r.returncode == 0, r.stderr[-3000:]
        yield {"hub": hub, "tmp": tmp, "home": home, "commit": json.loads(r.stdout.strip().splitlines()[-1])["commit"],
               "card": read_card(catalogue / CARD.name)}  # fmt: skip


def test_publishing_the_committed_weights_gives_the_pinned_commit_and_card(published):
    card, fresh = read_card(CARD), published["card"]
    assert published["commit"] == card.revision, "the loopback Hub changed: run `tools/finetune_warm.py --publish-only`"
    assert fresh.files == card.files and fresh.repo_id == card.repo_id
    same_day = fresh.__class__(**{**fresh.__dict__, "published": card.published})
    assert render_card(same_day) == CARD.read_text(encoding="utf-8")  # the committed card is what publishing writes


def test_loads_by_name_from_the_loopback_hub_then_offline(published, tmp_path):
    env = client_env(published["hub"].url, tmp_path, published["home"])
    out = run_worker([{"op": "download", "spec": NAME}, {"op": "load", "spec": NAME}], env)
    assert all(o["ok"] for o in out), out
    got = out[0]["result"]
    assert got["source"] == "hub" and got["verified"] == "card" and got["revision"] == read_card(CARD).revision
    assert got["files"]["model.safetensors"] == sha256_file(WEIGHTS / "model.safetensors")
    assert "romeo" in out[1]["result"]["targets"]
    n = len(published["hub"].requests)
    again = run_worker([{"op": "load", "spec": NAME}], {**env, "HF_HUB_OFFLINE": "1"})
    assert again[0]["ok"], again
    assert len(published["hub"].requests) == n  # from the cache, no request


def test_mer_retarget_by_name_to_romeo_offline(published, tmp_path, shared_wild_robots, monkeypatch):
    from model_helpers import synthetic_csv

    from mer_data.robots.register import register_robot
    from mer_data.robots.registry import get_skeleton

    urdf = shared_wild_robots / "romeo" / "romeo.urdf"
    if not urdf.is_file():
        pytest.skip(f"{urdf} is absent")
    home = tmp_path / "home"
    monkeypatch.setenv("MER_HOME", str(home))
    register_robot("romeo", urdf)
    env = client_env(published["hub"].url, tmp_path, home)
    assert run_worker([{"op": "download", "spec": NAME}], env)[0]["ok"]  # cached once, online
    n = len(published["hub"].requests)
    src = synthetic_csv(tmp_path / "walk.csv", frames=45, seed=2)
    r = subprocess.run([sys.executable, "-m", "mer_models", "retarget", str(src), "--source", "g1", "--target", "romeo",
                        "--model", NAME, "-o", str(tmp_path / "romeo.csv")], env=_env({**env, "HF_HUB_OFFLINE": "1"}),
                       capture_output=True, text=True, timeout=300, cwd=str(REPO))  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    assert "warm+refine2" in r.stderr and len(published["hub"].requests) == n
    m = np.loadtxt(tmp_path / "romeo.csv", delimiter=",")
    assert m.shape == (45, 7 + get_skeleton("romeo").num_dof) and np.isfinite(m).all()
