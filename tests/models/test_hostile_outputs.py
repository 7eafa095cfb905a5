"""Outputs and the viewer against strangers (issue 51): unwritable outputs refused before the job with
one line and exit 1, files mer did not write never replaced, the viewer's websocket closed to other
origins and ended cleanly by SIGTERM."""

from __future__ import annotations

import shutil
import signal
import socket
import subprocess
import sys

import hostile_sources as hs
import pytest
import torch

from mer_models.cli import main

BUILD = ["shards", "build", "--synthetic", "1", "--robots", "g1", "--targets", "g1", "--augment", "0", "--split", "all"]


def test_shards_build_never_replaces_a_readme_it_did_not_write(tmp_path, capsys):
    (tmp_path / "README.md").write_text("# my project\n")
    assert main([*BUILD, "--out", str(tmp_path)]) == 1
    assert (tmp_path / "README.md").read_text() == "# my project\n"
    assert "was not written by mer" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["README.md"]  # refused before anything was written
    out = tmp_path / "own"
    assert main([*BUILD, "--out", str(out)]) == 0
    assert main([*BUILD, "--out", str(out)]) == 0  # its own card: rebuilt in place


def test_an_output_folder_that_is_a_file_is_refused_before_the_job(tmp_path, capsys):
    (tmp_path / "f").write_text("x\n")
    assert main([*BUILD, "--out", str(tmp_path / "f")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "is not a folder" in err and "Traceback" not in err


@pytest.mark.skipif(shutil.which("unshare") is None, reason="needs unshare(1) for a read-only mount")
def test_a_read_only_output_folder_is_one_line_and_exit_1(tmp_path):
    csv = hs.g1_csv(tmp_path / "g1.csv", 20)
    ro = tmp_path / "ro"
    ro.mkdir()
    code = ("import sys; from mer_models.cli import main; sys.exit(main(sys.argv[1:]))")
    script = f'mount -t tmpfs -o ro,size=64k tmpfs {ro} || exit 99; exec "$@"'
    r = subprocess.run(["unshare", "-rm", "sh", "-c", script, "sh", sys.executable, "-c", code, "retarget", str(csv), "--source",
                        "g1", "--target", "g1", "-o", str(ro / "o.csv")], capture_output=True, text=True, timeout=300)  # fmt: skip
    if r.returncode == 99:
        pytest.skip("mounting in a user namespace is not allowed here")
    assert r.returncode == 1 and "read-only file system" in r.stderr and "Traceback" not in r.stderr, r.stderr[-800:]


# ---- the viewer -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def viewer():
    pytest.importorskip("viser", reason="the viewer's package is not installed (pip install -e '.[dev]')")
    from mer_data.kinematics.rotations import quat_to_matrix
    from mer_data.robots.registry import load_robot
    from mer_models.export.geometry import robot_meshes
    from mer_models.export.viewer import serve_motion
    from mer_models.export.writers import TargetMotion
    from mer_models.training.synthetic import synthetic_motion

    g1 = load_robot("g1")
    m = synthetic_motion(g1.skeleton, 10, seed=1)
    motion = TargetMotion(g1.skeleton, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())
    with serve_motion(motion, robot=g1, meshes=robot_meshes(g1, visual=False), port=0, play=False) as v:
        yield int(v.url.rsplit(":", 1)[1].strip("/"))


def _handshake(port: int, origin: str | None) -> bool:
    import viser
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    try:
        with connect(f"ws://127.0.0.1:{port}", origin=origin, subprotocols=[f"viser-v{viser.__version__}"], open_timeout=10) as ws:
            ws.recv(timeout=10)  # the scene starts coming
            return True
    except InvalidStatus as exc:
        assert exc.response.status_code == 403
        return False


def test_the_viewer_answers_its_own_page_only(viewer):
    assert not _handshake(viewer, "http://evil.example.com")
    assert not _handshake(viewer, f"http://evil.example.com:{viewer}")
    assert not _handshake(viewer, "http://127.0.0.1:1")  # another port of this machine: another page
    assert _handshake(viewer, f"http://127.0.0.1:{viewer}") and _handshake(viewer, f"http://localhost:{viewer}")
    assert _handshake(viewer, None)  # no Origin: not a web page


def test_origin_rule():
    from mer_models.export.viewer_guard import origin_allowed

    assert origin_allowed("http://[::1]:8080", "127.0.0.1", 8080)
    assert origin_allowed("http://myhost:8080", "myhost", 8080) and not origin_allowed("http://myhost:8080", "0.0.0.0", 8080)
    assert not origin_allowed("file://", "127.0.0.1", 8080) and not origin_allowed("null", "127.0.0.1", 8080)


def test_sigterm_ends_mer_view_with_close_frames(tmp_path):
    pytest.importorskip("viser", reason="the viewer's package is not installed (pip install -e '.[dev]')")
    import viser
    from websockets.exceptions import ConnectionClosedOK
    from websockets.sync.client import connect

    csv = hs.g1_csv(tmp_path / "g1.csv", 20)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code = "import sys; from mer_models.cli import main; sys.exit(main(sys.argv[1:]))"
    p = subprocess.Popen([sys.executable, "-c", code, "view", str(csv), "--robot", "g1", "--port", str(port), "--paused",
                          "--collision"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        line = ""
        while "viewing" not in line:  # viser prints its banner first
            line = p.stdout.readline()
            assert line, p.stderr.read()
        port = int(line.split("http://127.0.0.1:", 1)[1].split()[0].strip("/"))  # the port it took
        with connect(f"ws://127.0.0.1:{port}", origin=f"http://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"],
                     open_timeout=30) as ws:  # fmt: skip
            ws.recv(timeout=30)
            p.send_signal(signal.SIGTERM)
            with pytest.raises(ConnectionClosedOK):
                while True:
                    ws.recv(timeout=30)
        assert p.wait(timeout=30) == 0
        assert "Traceback" not in p.stderr.read()
    finally:
        if p.poll() is None:
            p.kill()
