"""`--video`: the scaled reference and the retarget side by side, as GIF (Pillow) or MP4 (ffmpeg)."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
import torch
from model_helpers import synthetic_csv
from PIL import Image

from mer_data.base.errors import MerError, OutputError
from mer_data.kinematics.rotations import quat_to_matrix
from mer_data.robots.registry import get_skeleton
from mer_models.cli import main
from mer_models.export import video as video_mod
from mer_models.export.video import check_video_path, find_ffmpeg, video_frame_indices, write_video
from mer_models.export.writers import TargetMotion
from mer_models.training.synthetic import synthetic_motion

SIZE = (320, 160)


def _motion(frames: int = 20, drift: float = 0.0, seed: int = 0) -> TargetMotion:
    """A synthetic G1 motion; ``drift`` [m] moves the base along +x linearly from frame 0 to the last."""
    s = get_skeleton("g1")
    m = synthetic_motion(s, frames, seed=seed)
    base = m["base_pos"] + np.linspace(0.0, drift, frames)[:, None] * [1.0, 0.0, 0.0]
    return TargetMotion(s, 30.0, m["q"], base, quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())


def _reference_of(m: TargetMotion) -> dict:
    """The motion itself as the 'scaled reference' (its nodes, bones and key points)."""
    pos, _ = m.forward_kinematics()
    key = [j for j in m.skeleton.keypoints.values() if j >= 0]
    return {"reference_points": pos[:, key], "reference_nodes": pos, "reference_skeleton": m.skeleton}


def _gif_frames(path) -> tuple[list[np.ndarray], list[int]]:
    with Image.open(path) as im:
        frames, durations = [], []
        for i in range(im.n_frames):
            im.seek(i)
            frames.append(np.asarray(im.convert("RGB")))
            durations.append(im.info["duration"])
    return frames, durations


def _leftovers(folder) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.startswith(".tmp-")]


def test_a_gif_has_one_frame_per_motion_frame_at_the_size_asked(tmp_path):
    m = _motion(20)
    out = write_video(tmp_path / "v.gif", m, size=SIZE, fps=30.0, **_reference_of(m))
    frames, durations = _gif_frames(out)
    assert len(frames) == 20 and frames[0].shape == (SIZE[1], SIZE[0], 3)
    assert sum(durations) == 670  # 20 frames at 30 Hz = 0.667 s, in GIF's centiseconds
    assert set(durations) <= {30, 40}
    half = write_video(tmp_path / "h.gif", m, size=SIZE, fps=10.0, **_reference_of(m))  # every third frame
    with Image.open(half) as im:
        assert im.n_frames == len(video_frame_indices(20, 30.0, 10.0)) == 7
    assert not _leftovers(tmp_path)


def _ink(rgb: np.ndarray) -> np.ndarray:
    """Columns holding stick-figure colour (saturated pixels; panes, grid and text are grey or black)."""
    sat = rgb.max(-1).astype(int) - rgb.min(-1).astype(int)
    return np.flatnonzero((sat > 60).any(0))


def test_the_two_panels_differ_where_the_motions_differ(tmp_path):
    """The robot = the reference drifting 0.8 m along +x: the same place at frame 0, apart at the end
    (the robot drawn with its collision shapes, the reference with its bones: compared by where
    their colour is centred)."""
    ref = _motion(12)
    robot = _motion(12, drift=0.8)
    frames, _ = _gif_frames(write_video(tmp_path / "v.gif", robot, size=SIZE, **_reference_of(ref)))
    w = SIZE[0] // 2
    first, last = frames[0], frames[-1]
    left, right = _ink(first[:, :w]), _ink(first[:, w:])
    assert len(left) > 10 and len(right) > 10 and abs(left.mean() - right.mean()) <= 4
    left, right = _ink(last[:, :w]), _ink(last[:, w:])
    assert abs(right.mean() - left.mean()) > 15  # 0.8 m apart: the robot is drawn elsewhere than the reference


@pytest.mark.parametrize("name", ["out.avi", "out", "out.GIF.txt"])
def test_an_unknown_ending_is_a_clear_error_and_writes_nothing(tmp_path, name):
    m = _motion(5)
    with pytest.raises(MerError, match=r"unknown video format") as e:
        write_video(tmp_path / name, m, size=SIZE, **_reference_of(m))
    assert ".gif" in str(e.value) and "fix:" in str(e.value)
    assert list(tmp_path.iterdir()) == []


def test_mp4_without_ffmpeg_names_what_to_install(monkeypatch, tmp_path):
    monkeypatch.setattr(video_mod, "find_ffmpeg", lambda: None)
    with pytest.raises(MerError, match="ffmpeg") as e:
        check_video_path(tmp_path / "v.mp4")
    assert "install ffmpeg" in str(e.value) and ".gif" in str(e.value)
    assert check_video_path(tmp_path / "v.gif") == "gif"  # GIF needs nothing more
    with pytest.raises(MerError, match="too fast for a GIF"):
        check_video_path(tmp_path / "v.gif", 60.0)


@pytest.mark.skipif(find_ffmpeg() is None, reason="no ffmpeg program (apt install ffmpeg or pip install imageio-ffmpeg)")
def test_an_mp4_decodes_to_the_frames_written(tmp_path):
    m = _motion(12)
    out = write_video(tmp_path / "v.mp4", m, size=SIZE, **_reference_of(m))
    assert out.read_bytes()[4:8] == b"ftyp"
    raw = subprocess.run([find_ffmpeg(), "-loglevel", "error", "-i", str(out), "-f", "rawvideo", "-pix_fmt", "rgb24", "-"],
                         capture_output=True, check=True).stdout  # fmt: skip
    assert len(raw) == 12 * SIZE[0] * SIZE[1] * 3
    assert not _leftovers(tmp_path)


@pytest.mark.parametrize("ext", ["gif", "mp4"])
def test_a_failure_while_rendering_leaves_nothing_half_written(tmp_path, monkeypatch, ext):
    if ext == "mp4" and find_ffmpeg() is None:
        pytest.skip("no ffmpeg program")
    m = _motion(10)
    path = tmp_path / f"v.{ext}"
    path.write_bytes(b"the earlier video")
    real = video_mod.VideoRenderer.frame

    def frame(self, f):
        if f == 5:
            raise RuntimeError("rendering broke")
        return real(self, f)

    monkeypatch.setattr(video_mod.VideoRenderer, "frame", frame)
    with pytest.raises(RuntimeError, match="rendering broke"):
        write_video(path, m, size=SIZE, fps=30.0, **_reference_of(m))
    assert path.read_bytes() == b"the earlier video" and not _leftovers(tmp_path)
    bad = TargetMotion(m.skeleton, 30.0, np.where(np.arange(10)[:, None] == 3, np.nan, m.q), m.base_pos, m.base_rot)
    with pytest.raises(OutputError):
        write_video(tmp_path / f"nan.{ext}", bad, size=SIZE, **_reference_of(m))
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]


def test_mer_retarget_writes_the_video_and_refuses_a_bad_ending_before_any_work(tmp_path, capsys):
    src = synthetic_csv(tmp_path / "walk.csv", frames=30)
    base = ["retarget", str(src), "--source", "g1", "--target", "h1", "--method", "optimize"]
    code = main([*base, "-o", str(tmp_path / "h1.csv"), "--video", str(tmp_path / "h1.avi")])
    err = capsys.readouterr().err
    assert code == 1 and "unknown video format '.avi'" in err and not (tmp_path / "h1.csv").exists()
    code = main([*base, "--video", str(tmp_path / "h1.gif"), "--video-fps", "15"])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert f"wrote video: {tmp_path / 'h1.gif'}" in out.out
    with Image.open(tmp_path / "h1.gif") as im:
        assert im.n_frames == 15 and im.size == (800, 400)


def test_a_gif_defaults_to_15_hz_and_the_first_10_s_and_a_range_picks_a_part(tmp_path, caplog):
    m = _motion(12 * 30)  # 12 s
    with caplog.at_level("WARNING"):
        out = write_video(tmp_path / "d.gif", m, size=SIZE, **_reference_of(m))
    assert "showing the first 10 s of" in caplog.text
    frames, durations = _gif_frames(out)
    assert len(frames) == 151 and sum(durations) == 10_070  # 0..10 s at 15 Hz; the clock kept
    part = write_video(tmp_path / "p.gif", m, size=SIZE, fps=30.0, time_range=(11.0, None), **_reference_of(m))
    assert len(_gif_frames(part)[0]) == 30  # 11.0 .. 11.967 s
    with pytest.raises(MerError, match="holds no frame"):
        write_video(tmp_path / "n.gif", m, size=SIZE, time_range=(20.0, 30.0), **_reference_of(m))
    assert not (tmp_path / "n.gif").exists()


@pytest.mark.parametrize("text, want", [("0:10", (0.0, 10.0)), (":5", (0.0, 5.0)), ("30:", (30.0, None)), ("1.5:2", (1.5, 2.0))])
def test_time_ranges_parse(text, want):
    assert video_mod.parse_time_range(text) == want


@pytest.mark.parametrize("text", ["5", "10:5", "-1:3", "a:b", "3:3", "nan:4"])
def test_bad_time_ranges_are_refused(text):
    with pytest.raises(MerError, match="START:END"):
        video_mod.parse_time_range(text)


def test_the_camera_follows_the_robot(tmp_path):
    """A robot walking 3 m stays where it was in the picture (its colour in the same columns)."""
    m = _motion(30, drift=3.0)
    frames, _ = _gif_frames(write_video(tmp_path / "f.gif", m, size=SIZE, fps=30.0, **_reference_of(m)))
    first, last = _ink(frames[0][:, SIZE[0] // 2 :]), _ink(frames[-1][:, SIZE[0] // 2 :])
    assert abs(float(np.median(first)) - float(np.median(last))) < 0.1 * SIZE[0] / 2
