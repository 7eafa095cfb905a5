"""mjlab's own motion-tracking environment on a robot mjlab does not ship: ``mer robots export NAME
--mjlab DIR`` with a mer npz (``--npz-for mjlab``), the folder moved elsewhere, then, in mjlab's
Python (a separate environment: mjlab pins its own MuJoCo), tests/models/export/mjlab_check.py
builds the tracking task the folder registers on the CPU, resets it, steps it 100 times with zero
actions, and reports what the environment read; then its play task (no randomisation), reset to the
motion's first frame, where mjlab's kinematics of the folder's model must put every body where the
npz says. Robots: Unitree H1 (a URDF), HighTorque Hi
registered from its MJCF (../shared/robots-mjcf) with its meshes, and a humanoid built in code with a
mimic joint, a locked joint and a mesh.

mjlab is found through ``MER_MJLAB_PYTHON`` (its interpreter; docs/trackers.md says how to install
it), else in this interpreter; without either the test is skipped, saying so. The first run compiles
mujoco_warp's CPU kernels (about a minute; cached in ~/.cache/warp after).
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
from test_mjlab_export import _toy, npz_for

from mer_data.robots.articulation import articulation
from mer_data.robots.register import register_robot
from mer_data.robots.registry import load_robot
from mer_models.cli import main

CHECK = Path(__file__).with_name("mjlab_check.py")


def _mjlab_python() -> str:
    exe = os.environ.get("MER_MJLAB_PYTHON")
    if exe:
        if not Path(exe).is_file():
            pytest.skip(f"MER_MJLAB_PYTHON={exe} is not a file")
        return exe
    try:
        import mjlab  # noqa: F401
    except ImportError:
        pytest.skip("mjlab is not installed: set MER_MJLAB_PYTHON to the python of a venv with mjlab 1.6 (docs/trackers.md)")
    return sys.executable


def _robot(name, tmp_path, shared_dir):
    if name == "h1":
        return load_robot("h1"), []
    if name == "toy":  # built in code: a mimic joint (no actuator), a locked joint, a mesh, massless bodies
        return _toy(tmp_path), []
    xml = shared_dir / "robots-mjcf" / "gmr_hightorque_hi" / "hi_25dof.xml"
    if not xml.is_file():
        pytest.skip(f"{xml} is absent")
    return register_robot("hi", xml).robot, ["--meshes", str(xml.parent / "meshes")]


@pytest.mark.parametrize("name", ["h1", "hi", "toy"])
def test_mjlab_tracking_env_loads_and_steps_the_exported_robot(name, tmp_path, capsys, request):
    python = _mjlab_python()
    shared_dir = request.getfixturevalue("shared_dir") if name == "hi" else None
    robot, extra = _robot(name, tmp_path, shared_dir)
    npz = npz_for(robot, tmp_path / f"{name}_walk.npz", frames=60)
    built = tmp_path / "built"
    assert main(["robots", "export", name, "--mjlab", str(built), "--motion", str(npz), *extra]) == 0
    capsys.readouterr()
    folder = tmp_path / "moved" / f"{name}_for_mjlab"  # the folder moved elsewhere still loads
    folder.parent.mkdir()
    shutil.move(str(built), str(folder))
    pkg = f"mer_{name}"
    motion = folder / pkg / "motions" / npz.name
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "MER_HOME")}
    env.setdefault("MUJOCO_GL", "disable")
    run = subprocess.run([python, str(CHECK), str(folder), pkg, str(motion), "100"], capture_output=True, text=True,
                         timeout=900, env=env, cwd=tmp_path)  # fmt: skip
    line = next((x for x in run.stdout.splitlines() if x.startswith("MJLAB_CHECK ")), None)
    assert run.returncode == 0 and line is not None, run.stderr[-3000:]
    got = json.loads(line[len("MJLAB_CHECK ") :])
    print(
        f"{name}: {json.dumps({k: got[k] for k in ('task', 'anchor', 'num_actions', 'fps', 'frames', 'diff', 'replay', 'steps', 'finite', 'seconds')})}"
    )
    z = np.load(npz, allow_pickle=False)
    assert got["joint_names"] == list(z["joint_names"]) and got["body_names"] == list(z["body_names"])
    driven = [j.name for j in articulation(robot).joints if j.mimic is None]  # every joint but the mimic ones
    assert got["num_actions"] == got["num_actuators"] == len(driven) == len(z["joint_names"]) - (name == "toy")
    assert got["fps"] == [50.0, "float64"] and got["frames"] == z["joint_pos"].shape[0]
    assert len(got["tracked"]) >= 12 and got["tracked"][0] == got["body_names"][0]
    assert max(got["diff"].values()) < 1e-6, got["diff"]  # the reference the env reads is the npz's, body by body
    assert got["steps"] == 100 and got["finite"]
    # mjlab's own forward kinematics of the folder's model, reset to the motion's first frame: every
    # body where the npz says (float32)
    assert got["replay"]["body_pos"] < 1e-5 and got["replay"]["body_quat"] < 1e-5, got["replay"]
