"""The MCAP carries the robot: TF frames are the URDF's links (where Foxglove's URDF layer attaches
each link's visuals), /robot_description is the URDF, /robot its collision shapes on those frames.

Every message validates against the schema embedded in the file (tests/foxglove_viewer.py). The
oracle for the frames is MuJoCo: the URDF compiled with every link kept as a body (no fusing),
qpos from the same motion's npz, each link's pose from ``mj_kinematics``.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from foxglove_viewer import check_mcap, mcap_messages, tf_world
from lxml import etree

from mer_data.kinematics.rotations import quat_to_matrix
from mer_data.robots.registry import load_robot
from mer_models.export.writers import TargetMotion, write_mcap, write_npz
from mer_models.training.synthetic import synthetic_motion

mujoco = pytest.importorskip("mujoco", reason="MuJoCo computes the links' poses (pip install -e .)")
pytest.importorskip("jsonschema", reason="jsonschema validates the MCAP messages (pip install -e '.[dev]')")


@pytest.mark.parametrize("name", ["g1", "talos"])  # talos: 14 locked joints, links behind them
def test_tf_frames_are_the_urdf_links_where_mujoco_puts_them(tmp_path, name):
    r = load_robot(name)
    s = r.skeleton
    m = synthetic_motion(s, 12, seed=4)
    motion = TargetMotion(s, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())
    path = write_mcap(tmp_path / f"{name}.mcap", motion, reference_points=np.zeros((12, 2, 3)))
    counts = check_mcap(path)  # every message against its embedded schema
    assert counts == {"/tf": 12, "/skeleton": 1, "/robot": 1, "/robot_description": 1, "/reference": 12}
    msgs = mcap_messages(path)
    urdf = msgs["/robot_description"][0][1]["data"]
    assert urdf == r.urdf_path.read_text()
    links = {el.get("name") for el in etree.fromstring(urdf.encode()).findall("link")}
    frames = {t["child_frame_id"] for t in msgs["/tf"][0][1]["transforms"]}
    assert frames == links  # every URDF link is a frame, named as the link (no joint names, no prefix)
    assert {e["frame_id"] for e in msgs["/robot"][0][1]["entities"]} <= frames
    assert {e["frame_id"] for e in msgs["/skeleton"][0][1]["entities"]} <= frames

    root = etree.fromstring(urdf.encode())
    for el in root.xpath("//visual|//collision|//inertial|//mujoco"):
        el.getparent().remove(el)
    spec = mujoco.MjSpec.from_string(etree.tostring(root).decode())
    spec.compiler.fusestatic = False  # every link a body
    spec.compiler.boundmass, spec.compiler.boundinertia = 1e-3, 1e-6
    spec.worldbody.first_body().add_freejoint()
    model = spec.compile()
    data = mujoco.MjData(model)
    z = np.load(write_npz(tmp_path / f"{name}.npz", motion, tracker="mjlab", fps=None))  # the same frames, 30 Hz
    qadr = [int(model.joint(str(n)).qposadr[0]) for n in z["joint_names"]]
    err = 0.0
    for f in (0, 5, 11):
        data.qpos[:3], data.qpos[3:7], data.qpos[qadr] = z["body_pos_w"][f, 0], z["body_quat_w"][f, 0], z["joint_pos"][f]
        mujoco.mj_kinematics(model, data)
        for link in links:
            t = tf_world(msgs["/tf"][f][1]["transforms"], link)
            b = model.body(link).id
            err = max(err, float(np.abs(t[:3, 3] - data.xpos[b]).max()), float(np.abs(t[:3, :3] - data.xmat[b].reshape(3, 3)).max()))
    assert err < 2e-5, err  # rounding of the JSON numbers (1e-6 m, 1e-7) and the npz's float32


def test_an_unregistered_skeleton_gets_its_nodes_links(tmp_path):
    s = load_robot("h1").skeleton.with_link_scales(np.full(24, 1.1))  # augmented: no registered robot has it
    m = synthetic_motion(s, 5, seed=1)
    motion = TargetMotion(s, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())
    path = write_mcap(tmp_path / "a.mcap", motion)
    assert check_mcap(path) == {"/tf": 5, "/skeleton": 1}
    frames = {t["child_frame_id"] for t in mcap_messages(path)["/tf"][0][1]["transforms"]}
    assert frames == {s.link_names[j] for j in range(s.num_nodes) if s.node_kinds[j] != "site"}
