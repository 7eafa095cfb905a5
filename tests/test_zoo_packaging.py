"""An installed wheel carries the catalogue: cards, card template and bundled weights are package data."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    src = out / "src"  # build from a copy: the build must not write into the checkout
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(".git", "*.egg-info", "build", "dist", "__pycache__", ".pytest_cache", ".hypothesis", "runs", "out", "shards", "*.h5", "*.hdf5", "*.mcap", "*.npz"))
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out), str(src)],
                          capture_output=True, text=True, timeout=300)
    if proc.returncode != 0:
        pytest.skip(f"cannot build a wheel here (pip/setuptools missing?): {proc.stderr[-500:]}")
    return next(out.glob("mer-*.whl"))


def test_the_wheel_ships_every_card_and_the_template(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for card in (REPO / "cards" / "models").glob("*.md"):
        assert f"mer_models/cards/{card.name}" in names
    assert "mer_models/templates/model_card.md" in names
    for folder in (REPO / "mer_models" / "bundled").glob("*/"):
        for f in folder.iterdir():
            assert f"mer_models/bundled/{folder.name}/{f.name}" in names


def test_list_models_works_from_the_installed_wheel(wheel, tmp_path):
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(PYTHONPATH=str(site), MER_HOME=str(tmp_path / "home"), HF_HUB_OFFLINE="1")
    code = ("import json, mer_models.zoo as z, mer_models.zoo.registry as r;"
            "print(json.dumps([str(r.builtin_cards_dir()), [[e.name, z.where(e)] for e in z.list_models()]]))")
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=str(tmp_path), timeout=120)
    assert proc.returncode == 0, proc.stderr
    where, models = json.loads(proc.stdout)
    assert where == str(site / "mer_models" / "cards")  # the packaged copy, not the checkout
    assert {m[0] for m in models} == {p.stem for p in (REPO / "cards" / "models").glob("*.md")}
