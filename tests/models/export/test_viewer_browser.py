"""The viewer (``mer view``, viser) in a real headless browser: Debian's chromium, driven by
playwright, loads the page from the viewer's loopback server; a screenshot shows the robot's meshes
where the robot stands, and the same check fails on the page of the same motion with the meshes
not drawn (collision shapes instead); a built-in (its shipped meshes) is one connected robot.

Skipped with the reason where chromium, playwright or viser is absent (the README's test command
installs all three), or where ``../shared/robots-mjcf`` (the G1 with meshes) is absent.
"""

from __future__ import annotations

import io
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from mer_data.kinematics.rotations import quat_to_matrix
from mer_data.robots.register import register_robot
from mer_data.robots.registry import load_robot
from mer_models.export.geometry import robot_meshes
from mer_models.export.viewer import VIEWER_MAX_FACES, serve_motion
from mer_models.export.writers import TargetMotion
from mer_models.training.synthetic import synthetic_motion

pytest.importorskip("viser", reason="the viewer's package is not installed (pip install -e '.[dev]')")
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright drives the browser (pip install -e '.[dev]')")
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
if not Path(CHROMIUM).is_file():
    pytest.skip(
        "no chromium to load the page in (apt-get install chromium; the README's test command does)", allow_module_level=True
    )
# as root, headless, no network beyond loopback (python.md: the flags Debian's chromium needs here)
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync"]  # fmt: skip
VIEW = {"width": 1280, "height": 720}


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    with sync_api.sync_playwright() as p:
        profile = tmp_path_factory.mktemp("chromium-profile")  # a fresh user data dir
        ctx = p.chromium.launch_persistent_context(str(profile), executable_path=CHROMIUM, headless=True, args=FLAGS,
                                                   viewport=VIEW)  # fmt: skip
        yield ctx
        ctx.close()


@pytest.fixture
def g1m(shared_dir: Path):
    d = shared_dir / "robots-mjcf" / "mjlab_unitree_g1"
    if not (d / "g1.xml").is_file() or not (d / "assets").is_dir():
        pytest.skip(f"mjlab's G1 MJCF with its meshes is absent from {d}")
    robot = register_robot("g1m", d / "g1.xml").robot
    shutil.copytree(d / "assets", robot.folder / "assets")  # where registration says to put them
    return load_robot("g1m")


def _region(rgb: np.ndarray) -> np.ndarray:
    """Where the robot stands: the middle of the view (the camera looks at it), clear of the panel
    (top right), the axes (bottom left) and the notice (top left)."""
    h, w = rgb.shape[:2]
    return rgb[int(0.15 * h) : int(0.9 * h), int(0.25 * w) : int(0.7 * w)].astype(int)


def mesh_pixels(rgb: np.ndarray) -> int:
    """Pixels of the meshes' light blue (mer_models.export.viewer.MESH_RGB, lit) where the robot stands."""
    a = _region(rgb)
    return int(((a[..., 2] - a[..., 0] > 50) & (a[..., 2] - a[..., 1] > 20) & (a[..., 2] > 100)).sum())


def shape_pixels(rgb: np.ndarray) -> int:
    """Pixels of the collision shapes' amber (COLLISION_RGB, lit) where the robot stands."""
    a = _region(rgb)
    return int(((a[..., 0] - a[..., 2] > 60) & (a[..., 1] - a[..., 2] > 20) & (a[..., 0] > 100)).sum())


def screenshot(browser, url: str, out: Path, timeout: float = 120.0) -> np.ndarray:
    """The page at ``url`` once the robot is drawn (either colour), or after ``timeout`` s."""
    page = browser.new_page()
    try:
        page.goto(url)
        t0 = time.monotonic()
        while True:
            png = page.screenshot()
            rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
            if mesh_pixels(rgb) + shape_pixels(rgb) > 2000 or time.monotonic() - t0 > timeout:
                time.sleep(1.0)  # the last meshes of a frame
                png = page.screenshot()
                out.write_bytes(png)
                return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
            time.sleep(0.5)
    finally:
        page.close()


def test_the_viewer_page_shows_the_robots_meshes_and_the_check_fails_without_them(browser, g1m, tmp_path):
    s = g1m.skeleton
    m = synthetic_motion(s, 20, seed=2)
    motion = TargetMotion(s, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())
    meshes = robot_meshes(g1m, max_faces=20000)  # found beside the registered file; fewer faces: software WebGL
    assert meshes.kind == "mesh"
    with serve_motion(motion, robot=g1m, meshes=meshes, port=0, play=False) as v:
        assert v.url.startswith("http://127.0.0.1:")  # loopback only
        shot = screenshot(browser, v.url, tmp_path / "meshes.png")
    assert mesh_pixels(shot) > 3000, mesh_pixels(shot)
    # the same motion, the meshes not drawn: the robot is there (its shapes) and the check fails
    with serve_motion(motion, robot=g1m, meshes=robot_meshes(g1m, visual=False), port=0, play=False) as v:
        shot = screenshot(browser, v.url, tmp_path / "shapes.png")
    assert shape_pixels(shot) > 1500, shape_pixels(shot)
    assert mesh_pixels(shot) < 100, mesh_pixels(shot)


def bone_pixels(rgb: np.ndarray) -> np.ndarray:
    """Where the bones' dark grey (mer_models.export.viewer.BONE_RGB) is drawn, in the robot's region (mask)."""
    a = _region(rgb)
    return (a.max(-1) < 90) & (a.max(-1) - a.min(-1) < 25)


def robot_components(rgb: np.ndarray) -> tuple[int, float]:
    """The robot's pieces on screen (mesh blue, collision amber and bone grey, touching pixels
    joined): how many pieces of over 30 pixels, and the share of the robot's pixels in the largest."""
    from scipy import ndimage

    a = _region(rgb)
    amber = (a[..., 0] - a[..., 2] > 60) & (a[..., 1] - a[..., 2] > 20) & (a[..., 0] > 100)
    blue = (a[..., 2] - a[..., 0] > 50) & (a[..., 2] - a[..., 1] > 20) & (a[..., 2] > 100)
    mask = ndimage.binary_dilation(amber | blue | bone_pixels(rgb), iterations=2)  # anti-aliased edges between them
    labels, n = ndimage.label(mask)
    sizes = np.bincount(labels.ravel())[1:]
    return int((sizes > 30).sum()), float(sizes.max() / sizes.sum()) if n else 0.0


def test_a_builtin_robot_is_drawn_connected_with_its_meshes_or_by_its_bones(browser, tmp_path):
    """issue 52: a built-in's collision pieces floated apart in `mer view`. The G1 now ships its
    visual meshes and `mer view` draws them (one connected robot on screen); drawn by its collision
    shapes (as Valkyrie, which ships none), its bones join them into one piece, and with the bones
    off none is drawn."""
    g1 = load_robot("g1")
    s = g1.skeleton
    m = synthetic_motion(s, 20, seed=2)
    motion = TargetMotion(s, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())
    meshes = robot_meshes(g1, max_faces=VIEWER_MAX_FACES)  # what `mer view --target g1` draws
    assert meshes.kind == "mesh" and not meshes.missing  # its shipped meshes
    with serve_motion(motion, robot=g1, meshes=meshes, port=0, play=False) as v:
        shot = screenshot(browser, v.url, tmp_path / "builtin_meshes.png")
    pieces, largest = robot_components(shot)
    assert mesh_pixels(shot) > 3000 and shape_pixels(shot) < 100, (mesh_pixels(shot), shape_pixels(shot))
    assert pieces == 1 and largest > 0.99, (pieces, largest)
    shapes = robot_meshes(g1, visual=False)
    with serve_motion(motion, robot=g1, meshes=shapes, port=0, play=False) as v:
        shot = screenshot(browser, v.url, tmp_path / "builtin_shapes.png")
    pieces, largest = robot_components(shot)
    assert shape_pixels(shot) > 1500 and bone_pixels(shot).sum() > 200, (shape_pixels(shot), bone_pixels(shot).sum())
    assert pieces == 1 and largest > 0.99, (pieces, largest)
    with serve_motion(motion, robot=g1, meshes=shapes, port=0, play=False, bones=False) as v:
        shot = screenshot(browser, v.url, tmp_path / "no_bones.png")
    assert bone_pixels(shot).sum() < 50, bone_pixels(shot).sum()  # no bones: the check above cannot pass
