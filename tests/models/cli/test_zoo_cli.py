"""``mer zoo``: the commands a user types, run as processes against the loopback Hub."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from hub_server import HubServer
from zoo_helpers import TOKEN, client_env, make_checkpoint

from mer_models.cli import main
from mer_models.hub.card import read_card

REPO = Path(__file__).resolve().parents[3]


def _mer(args: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    base = {k: v for k, v in os.environ.items() if not k.startswith(("HF_", "HUGGINGFACE_"))}
    base.update(env)
    base["PYTHONPATH"] = str(REPO)
    return subprocess.run([sys.executable, "-m", "mer_models", *args], env=base, capture_output=True, text=True,
                          timeout=120, cwd=str(REPO))


def test_publish_download_list_from_the_command_line(tmp_path, mer_home):
    ck = make_checkpoint(tmp_path / "ck", seed=5)
    cards = tmp_path / "cards"
    with HubServer(token=TOKEN) as hub:
        env = client_env(hub.url, tmp_path, mer_home)
        r = _mer(["zoo", "publish", str(ck), "--name", "cli-model", "--repo-id", "lab/cli-model", "--cards-dir", str(cards)], env)
        assert r.returncode == 0, r.stderr
        card = read_card(cards / "cli-model.md")
        assert f"published cli-model as lab/cli-model@{card.revision}" in r.stdout
        assert card.files["model.safetensors"].sha256 in r.stdout

        # The card is the registry entry: put it where the user's registry reads cards.
        (mer_home / "cards" / "models").mkdir(parents=True)
        (mer_home / "cards" / "models" / "cli-model.md").write_bytes((cards / "cli-model.md").read_bytes())
        r = _mer(["zoo", "download", "cli-model"], env)
        assert r.returncode == 0, r.stderr
        assert f"lab/cli-model@{card.revision}" in r.stdout and "sha256 checked against the card" in r.stdout
        folder = Path(r.stdout.split(" -> ")[1].split(" (")[0])
        assert (folder / "model.safetensors").read_bytes() == (ck / "model.safetensors").read_bytes()

        n = len(hub.requests)
        r = _mer(["zoo", "list", "--json"], {**env, "HF_HUB_OFFLINE": "1"})
        assert r.returncode == 0, r.stderr
        rows = {row["name"]: row for row in json.loads(r.stdout)}
        assert rows["cli-model"]["where"] == "cached" and rows["cli-model"]["revision"] == card.revision
        assert rows["cli-model"]["size"] == card.size and rows["mer-paper"]["where"] == "unpublished"
        assert len(hub.requests) == n


def test_errors_exit_non_zero_with_what_to_do(capsys):
    assert main(["zoo", "download", "no-such-model"]) == 1
    err = capsys.readouterr().err
    assert "unknown model 'no-such-model'" in err and "mer-paper" in err and "fix:" in err
    assert main(["zoo", "download", "org/model", "--revision", "../../outside"]) == 1
    assert "invalid revision" in capsys.readouterr().err
    assert main(["zoo", "download", "mer-paper-talos"]) == 1
    err = capsys.readouterr().err
    assert "not yet published" in err and "mer finetune --base mer-paper --robot talos" in err


def test_info_is_short_by_default_and_whole_with_verbose(capsys):
    assert main(["zoo", "info", "mer-paper"]) == 0
    out = capsys.readouterr().out
    assert "unpublished" in out and "cc-by-nc-nd-4.0" in out and "not published yet" in out and "--verbose" in out
    assert "mer train --config paper" not in out and "@ not published" not in out
    assert main(["zoo", "info", "mer-paper", "--verbose"]) == 0
    out = capsys.readouterr().out
    assert "mer train --config paper" in out and "licence:" in out and "split:" in out
    assert main(["zoo", "info", "mer-base"]) == 0
    short = capsys.readouterr().out
    assert len(short) < 900 and len(short.splitlines()) <= 9, short
    assert "accuracy: E_g-mpbpe" in short and "model alone" in short
    assert "history" not in short and "function-preservingly" not in short and "repo:" not in short
    assert main(["zoo", "info", "mer-base", "--verbose"]) == 0
    full = capsys.readouterr().out
    assert "function-preservingly" in full and "sha256" in full and "repo:" not in full  # bundled: no Hub repo line


def test_model_typos_get_a_suggestion(capsys):
    assert main(["zoo", "download", "mer-bse"]) == 1
    assert "did you mean 'mer-base'?" in capsys.readouterr().err
    assert main(["zoo", "info", "mer-papr"]) == 1
    assert "did you mean 'mer-paper'?" in capsys.readouterr().err


def test_info_json_is_the_card(capsys):
    assert main(["zoo", "info", "mer-paper-talos", "--json"]) == 0
    meta = json.loads(capsys.readouterr().out)
    assert meta["base_model"] == "mer-paper" and meta["where"] == "unpublished" and meta["license"] == "cc-by-nc-nd-4.0"
