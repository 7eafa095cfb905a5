"""Independent FK implementations used as oracles: yourdfpy (numpy, float64) and pytorch_kinematics."""

from __future__ import annotations

import contextlib
import io
import re

import numpy as np
import torch

from mer_data.skeleton import Skeleton


def urdf_config(skel: Skeleton, q_nodes: np.ndarray) -> dict[str, float]:
    """URDF joint values for node angles ``q_nodes`` (J,): moving joints, mimics, locked joints."""
    cfg = {}
    for j, name in enumerate(skel.urdf_joint_names):
        if name is None:
            continue
        src = skel.mimic_source[j]
        cfg[name] = float(q_nodes[j] if src < 0 else skel.mimic_multiplier[j] * q_nodes[src] + skel.mimic_offset[j])
    cfg.update(skel.locked)
    return cfg


def yourdfpy_positions(urdf_path: str, skel: Skeleton, card, q_nodes: np.ndarray) -> np.ndarray:
    """(J, 3) node positions in the root frame from yourdfpy's own FK."""
    import yourdfpy

    u = yourdfpy.URDF.load(urdf_path, load_meshes=False, build_scene_graph=True)
    cfg = urdf_config(skel, q_nodes)
    u.update_cfg({k: v for k, v in cfg.items() if k in u.actuated_joint_names})
    out = np.zeros((skel.num_nodes, 3))
    for j in range(skel.num_nodes):
        t = u.get_transform(skel.link_names[j], u.base_link)
        off = np.zeros(3)
        if skel.node_kinds[j] == "site":
            off = np.asarray(card.keypoints[skel.node_names[j]].offset)
        out[j] = t[:3, :3] @ off + t[:3, 3]
    return out


def pk_chain(urdf_path: str, dtype: torch.dtype, exact_origins: bool = False):
    """A pytorch_kinematics chain of the URDF.

    Works around two quirks: nameless ``<material>`` tags (H1_2) that its parser rejects, and
    (``exact_origins``) its parsing of joint ``rpy`` and axes in float32 even for a float64 chain,
    which alone puts it ~1e-7 m off: with it, origins, axes and the chain are float64 throughout.
    """
    import pytorch_kinematics as pk
    import pytorch_kinematics.transforms as tf
    import pytorch_kinematics.urdf as pk_urdf

    text = open(urdf_path).read()
    text = re.sub(r"<material>\s*(<color[^>]*/>)?\s*</material>", "", text)
    text = re.sub(r"<\?xml[^>]*\?>", "", text)
    saved = (pk_urdf._convert_transform, pk_urdf.chain.Chain, pk_urdf.frame.Joint)

    def convert64(origin):
        if origin is None:
            return tf.Transform3d(dtype=torch.float64)
        rpy = torch.tensor(origin.rpy, dtype=torch.float64)
        return tf.Transform3d(
            rot=tf.quaternion_from_euler(rpy, "sxyz"), pos=torch.tensor(origin.xyz, dtype=torch.float64),
            dtype=torch.float64,
        )  # fmt: skip

    if exact_origins:
        pk_urdf._convert_transform = convert64
        class Chain64(saved[1]):
            def __init__(self, root_frame, dtype=torch.float64, device="cpu"):
                super().__init__(root_frame, dtype=dtype, device=device)

        class Joint64(saved[2]):
            def __init__(self, *args, **kw):
                kw.setdefault("dtype", torch.float64)
                super().__init__(*args, **kw)

        pk_urdf.chain.Chain = Chain64
        pk_urdf.frame.Joint = Joint64
    try:
        with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
            chain = pk.build_chain_from_urdf(text)
    finally:
        pk_urdf._convert_transform, pk_urdf.chain.Chain, pk_urdf.frame.Joint = saved
    return chain.to(dtype=dtype)


def pk_config(chain, skel: Skeleton, q_nodes: torch.Tensor) -> torch.Tensor:
    """(N, n_pk_joints) in the chain's own (depth-first) joint order, mapped by name."""
    cfg_names = chain.get_joint_parameter_names()
    th = torch.zeros(q_nodes.shape[0], len(cfg_names), dtype=q_nodes.dtype)
    node_of = {n: j for j, n in enumerate(skel.urdf_joint_names) if n is not None}
    for i, name in enumerate(cfg_names):
        if name in node_of:
            j = node_of[name]
            src = skel.mimic_source[j]
            th[:, i] = q_nodes[:, j] if src < 0 else skel.mimic_multiplier[j] * q_nodes[:, src] + skel.mimic_offset[j]
        elif name in skel.locked:
            th[:, i] = skel.locked[name]
    return th
