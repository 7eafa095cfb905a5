"""``mer view``: serves the page on loopback (a real process, a real HTTP request), refuses what it
cannot show with a clear message, and says how to install the viewer where viser is missing."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from model_helpers import synthetic_csv

from mer_models.cli import main

REPO = Path(__file__).resolve().parents[3]


def _retarget(tmp_path: Path, frames: int = 30) -> tuple[Path, Path]:
    src = synthetic_csv(tmp_path / "walk.csv", frames=frames)
    out = tmp_path / "h1.csv"
    assert (
        main(["retarget", str(src), "--source", "g1", "--target", "h1", "--method", "optimize", "--no-physics", "-o", str(out)])
        == 0
    )
    return src, out


def test_mer_view_serves_the_page_on_loopback(tmp_path, mer_home):
    pytest.importorskip("viser", reason="the viewer's package is not installed (pip install -e '.[dev]')")
    src, out = _retarget(tmp_path)
    env = {**os.environ, "MER_HOME": str(mer_home), "PYTHONUNBUFFERED": "1"}
    cmd = [sys.executable, "-m", "mer_models.cli", "view", str(out), "--robot", "h1", "--reference", str(src), "--source", "g1",
           "--port", "0", "--paused"]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line, t0 = "", time.monotonic()
        while "viewing" not in line and time.monotonic() - t0 < 120:
            line = proc.stdout.readline()
            assert line or proc.poll() is None, proc.stderr.read()
        assert "viewing h1 (30 frames, its meshes" in line, line  # the built-in h1 ships its visual meshes (issue 52)
        url = line.split(" at ", 1)[1].split()[0]
        assert url.startswith("http://127.0.0.1:")
        with urllib.request.urlopen(url, timeout=30) as r:
            page = r.read().decode("utf-8", "replace")
        assert r.status == 200 and "<html" in page.lower() and "<script" in page.lower()
    finally:
        proc.terminate()  # the process this test started
        proc.wait(timeout=30)


def test_mer_view_without_viser_names_the_install_command(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "viser", None)  # `import viser` raises ImportError
    code = main(["view", str(tmp_path / "missing.csv"), "--robot", "h1"])
    err = capsys.readouterr().err
    assert code == 1 and "viser package, which is not installed" in err and 'pip install "mer[viewer]"' in err


def test_mer_view_refuses_a_reference_that_is_not_the_motions_source(tmp_path, capsys):
    pytest.importorskip("viser", reason="the viewer's package is not installed (pip install -e '.[dev]')")
    _, out = _retarget(tmp_path)
    other = synthetic_csv(tmp_path / "other.csv", frames=45)
    code = main(["view", str(out), "--robot", "h1", "--reference", str(other), "--source", "g1", "--port", "0"])
    err = capsys.readouterr().err
    assert code == 1 and "the reference has 45 frames at 30 Hz, the motion 30" in err
    code = main(["view", str(out), "--robot", "h1", "--reference", str(other)])
    assert code == 1 and "--reference needs --source" in capsys.readouterr().err


def test_mer_view_refuses_a_motion_of_another_robot(tmp_path, capsys):
    pytest.importorskip("viser", reason="the viewer's package is not installed (pip install -e '.[dev]')")
    _, out = _retarget(tmp_path)  # an h1 motion read as a g1 one: its columns do not match
    code = main(["view", str(out), "--robot", "g1", "--port", "0"])
    assert code == 1 and "values on this line, expected 36" in capsys.readouterr().err
