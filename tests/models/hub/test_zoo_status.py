"""The zoo's statuses are true (issue 52, item 6): a model whose repository is on no public Hub is listed
as such, and loading it from the public Hub says so and where its weights are, before any request."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]


def _mer(args: list[str], tmp_path: Path, **env: str) -> subprocess.CompletedProcess:
    base = {k: v for k, v in os.environ.items() if not k.startswith(("HF_", "HUGGINGFACE_"))}
    env = {**base, "PYTHONPATH": str(REPO), "HF_HOME": str(tmp_path / "hf"), "MER_HOME": str(tmp_path / "mer"), **env}
    return subprocess.run([sys.executable, "-m", "mer_models", *args], env=env, capture_output=True, text=True, timeout=120)


def test_a_model_on_no_public_hub_is_listed_and_refused_as_such(tmp_path):
    r = _mer(["zoo", "list", "--json"], tmp_path)
    assert r.returncode == 0, r.stderr
    where = {row["name"]: row["where"] for row in json.loads(r.stdout)}
    assert where["mer-warm-romeo"] == "not on Hub" and where["mer-base"] == "bundled" and where["mer-paper"] == "unpublished"
    r = _mer(["zoo", "download", "mer-warm-romeo"], tmp_path)
    assert r.returncode == 1
    assert "'mer-warm-romeo' is on no public Hub yet" in r.stderr and "cannot download" not in r.stderr, r.stderr
    assert f"--model {REPO / 'cards' / 'weights' / 'mer-warm-romeo'}" in r.stderr  # where its weights are, in this checkout
    # another Hub (a mirror, the tests' loopback one) may hold it: listed as remote there, and asked
    r = _mer(["zoo", "list", "--json"], tmp_path, HF_ENDPOINT="http://127.0.0.1:9")
    assert {row["name"]: row["where"] for row in json.loads(r.stdout)}["mer-warm-romeo"] == "remote"
    r = _mer(["zoo", "download", "mer-warm-romeo"], tmp_path, HF_ENDPOINT="http://127.0.0.1:9")
    assert r.returncode == 1 and "cannot download" in r.stderr and "no public Hub" not in r.stderr, r.stderr
