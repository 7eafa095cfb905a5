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

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    src = out / "src"  # build from a copy: the build must not write into the checkout
    anywhere = shutil.ignore_patterns(".git", "*.egg-info", "__pycache__", ".pytest_cache", ".hypothesis", "*.h5", "*.hdf5", "*.mcap", "*.npz")

    def ignore(folder, names):  # work folders only at the top: mer_data/shards is a package
        top = {"build", "dist", "runs", "out", "shards"} if Path(folder) == REPO else set()
        return set(anywhere(folder, names)) | (top & set(names))

    shutil.copytree(REPO, src, ignore=ignore)
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
    for f in ("FrameTransforms.json", "SceneUpdate.json", "LICENSE"):  # Foxglove's official schemas (MCAP writers)
        assert f"mer_data/shards/foxglove_schemas/{f}" in names
    for folder in (REPO / "mer_models" / "bundled").glob("*/"):
        for f in folder.iterdir():
            assert f"mer_models/bundled/{folder.name}/{f.name}" in names
    # the bundled weights are the default model's and the warm start's, and only those (the retired demo model no longer ships)
    from mer_models.zoo import DEFAULT_MODEL

    bundled = {n.split("/")[2] for n in names if n.startswith("mer_models/bundled/")}
    assert bundled == {DEFAULT_MODEL, "mer-warm"} == {"mer-base", "mer-warm"}
    assert {"mer_models/cards/mer-base.md", "mer_models/cards/mer-warm.md"} <= names and not any("mer-tiny-synthetic" in n for n in names)


def test_list_models_works_from_the_installed_wheel(wheel, tmp_path):
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(PYTHONPATH=str(site), MER_HOME=str(tmp_path / "home"), HF_HUB_OFFLINE="1")
    code = ("import json, mer_models.zoo as z, mer_models.hub.registry as r;"
            "print(json.dumps([str(r.builtin_cards_dir()), [[e.name, z.where(e)] for e in z.list_models()]]))")
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=str(tmp_path), timeout=120)
    assert proc.returncode == 0, proc.stderr
    where, models = json.loads(proc.stdout)
    assert where == str(site / "mer_models" / "cards")  # the packaged copy, not the checkout
    assert {m[0] for m in models} == {p.stem for p in (REPO / "cards" / "models").glob("*.md")}


def test_the_installed_wheel_loads_and_retargets_with_the_default_model_offline(wheel, tmp_path):
    """A fresh install: the bundled weights are in the wheel, load by name with no network and no
    Hub cache, and `mer retarget` with no --model (the default model) runs from the installed package
    (not the checkout)."""
    from mer_data.robots.registry import BUILTIN_ROBOTS
    from mer_models.zoo import DEFAULT_MODEL

    names = set(zipfile.ZipFile(wheel).namelist())
    assert {f"mer_models/bundled/{DEFAULT_MODEL}/config.json", f"mer_models/bundled/{DEFAULT_MODEL}/model.safetensors"} <= names
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(PYTHONPATH=str(site), MER_HOME=str(tmp_path / "home"), HF_HUB_OFFLINE="1", HF_HUB_CACHE=str(tmp_path / "no-cache"))
    code = ("import json, mer_models, mer_models.zoo as z;"
            "r = z.resolve(z.DEFAULT_MODEL); c = z.load(z.DEFAULT_MODEL);"
            "print(json.dumps([mer_models.__file__, str(r.folder), r.source, r.verified, c.targets]))")
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=str(tmp_path), timeout=120)
    assert proc.returncode == 0, proc.stderr
    init, folder, source, verified, targets = json.loads(proc.stdout)
    assert init.startswith(str(site)) and folder == str(site / "mer_models" / "bundled" / DEFAULT_MODEL)
    assert (source, verified) == ("bundled", "card") and sorted(targets) == sorted(BUILTIN_ROBOTS)
    make_csv = ("import sys, torch; from mer_data.robots.registry import get_skeleton; from mer_data.kinematics.rotations import quat_to_matrix;"
                "from mer_models.training.synthetic import synthetic_motion; from mer_models.export.writers import TargetMotion, write_csv;"
                "s = get_skeleton('g1'); m = synthetic_motion(s, 30, seed=1);"
                "write_csv(sys.argv[1], TargetMotion(s, 30.0, m['q'], m['base_pos'], quat_to_matrix(torch.from_numpy(m['base_quat'])).numpy()))")
    subprocess.run([sys.executable, "-c", make_csv, str(tmp_path / "g1.csv")], env=env, check=True, cwd=str(tmp_path), timeout=120)
    proc = subprocess.run([sys.executable, "-m", "mer_models", "retarget", str(tmp_path / "g1.csv"), "--source", "g1", "--target", "h1",
                           "-o", str(tmp_path / "h1.csv"), "--steps", "1"],
                          env=env, capture_output=True, text=True, cwd=str(tmp_path), timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert f"no --model: using the bundled model {DEFAULT_MODEL!r}" in proc.stderr
    assert len((tmp_path / "h1.csv").read_text().splitlines()) == 30
    assert not (tmp_path / "no-cache").exists()
