"""SMPL-family body-model and motion files built in code (the real key layout and shapes, random but
valid values): body models are licensed and never shipped, so the tests make their own."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mer_data.motion.body_model import JOINT_NAMES, KINDS, PARENTS

# A standing T-pose of SMPL's 22 body joints [m] (y up, z forward, x the subject's left), rounded.
TPOSE22 = np.array([
    [0.0, 0.0, 0.0], [0.06, -0.09, 0.0], [-0.06, -0.09, 0.0], [0.0, 0.11, -0.02], [0.10, -0.47, 0.0],
    [-0.10, -0.47, 0.0], [0.0, 0.24, 0.0], [0.09, -0.87, -0.04], [-0.09, -0.87, -0.04], [0.0, 0.30, 0.02],
    [0.11, -0.93, 0.08], [-0.11, -0.93, 0.08], [0.0, 0.52, -0.01], [0.08, 0.43, -0.0], [-0.08, 0.43, -0.0],
    [0.0, 0.58, 0.04], [0.17, 0.46, -0.01], [-0.17, 0.46, -0.01], [0.43, 0.44, -0.03], [-0.43, 0.44, -0.03],
    [0.68, 0.45, -0.03], [-0.68, 0.45, -0.03],
])  # fmt: skip


def smpl_parents(kind: str) -> np.ndarray:
    """(J,) the SMPL family's parents: the 22 body joints, then hands / jaw, eyes, fingers."""
    J = KINDS[kind]
    par = list(PARENTS)
    if kind == "smpl":
        par += [20, 21]
    else:
        if kind == "smplx":
            par += [15, 15, 15]  # jaw, eyes
        for wrist in (20, 21):  # 5 fingers x 3 joints
            for _ in range(5):
                par += [wrist, len(par), len(par) + 1]
    assert len(par) == J
    return np.array(par)


def build_body_model(path: Path, kind: str = "smplh", *, seed: int = 0, verts_per_joint: int = 4,
                     num_betas: int | None = None) -> Path:
    """Write a body-model npz of ``kind`` with the real keys and shapes (fewer vertices)."""
    rng = np.random.default_rng(seed)
    par = smpl_parents(kind)
    J = len(par)
    joints = np.zeros((J, 3))
    joints[:22] = TPOSE22 + rng.normal(0, 0.005, (22, 3))
    for k in range(22, J):
        joints[k] = joints[par[k]] + rng.normal(0, 0.03, 3) + np.sign(joints[par[k], 0]) * np.array([0.03, 0, 0])
    V = J * verts_per_joint
    owner = np.repeat(np.arange(J), verts_per_joint)
    v = joints[owner] + rng.normal(0, 0.02, (V, 3))
    jr = np.zeros((J, V))
    jr[owner, np.arange(V)] = rng.uniform(0.5, 1.5, V)
    jr /= jr.sum(1, keepdims=True)
    S = num_betas or {"smpl": 10, "smplh": 16, "smplx": 400}[kind]
    w = np.zeros((V, J))
    w[np.arange(V), owner] = 1.0
    kt = np.stack([par, np.arange(J)]).astype(np.uint32)
    kt[0, 0] = 4294967295
    arrays = dict(
        v_template=v, shapedirs=rng.normal(0, 0.01, (V, 3, S)), J_regressor=jr, kintree_table=kt, weights=w,
        posedirs=rng.normal(0, 0.001, (V, 3, (J - 1) * 9)), f=rng.integers(0, V, (2 * V, 3)).astype(np.uint32),
    )  # fmt: skip
    if kind == "smplh":
        for s in "lr":
            arrays[f"hands_components{s}"] = np.linalg.qr(rng.normal(size=(45, 45)))[0]
            arrays[f"hands_mean{s}"] = rng.normal(0, 0.1, 45)
    if kind == "smplx":
        for s in "lr":
            arrays[f"hands_components{s}"] = np.linalg.qr(rng.normal(size=(45, 45)))[0]
            arrays[f"hands_mean{s}"] = rng.normal(0, 0.1, 45)
        arrays.update(lmk_faces_idx=np.arange(51, dtype=np.int64) % (2 * V),
                      lmk_bary_coords=np.full((51, 3), 1 / 3), dynamic_lmk_faces_idx=np.zeros((79, 17), np.int64),
                      dynamic_lmk_bary_coords=np.full((79, 17, 3), 1 / 3))  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **arrays)
    return path


def random_poses(T: int, J: int, seed: int = 0, scale: float = 0.3) -> np.ndarray:
    """(T, 3J) smooth random axis-angles (a root standing up in a z-up world: AMASS's)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, T)[:, None]
    a = rng.normal(0, scale, (1, 3 * J)) * np.sin(2 * np.pi * (t * rng.uniform(0.5, 2, (1, 3 * J)) + rng.uniform(0, 1, (1, 3 * J))))
    a[:, :3] = [np.pi / 2, 0, 0]  # body y up -> world z up
    a[:, :3] += rng.normal(0, 0.05, (1, 3))
    return a


__all__ = ["TPOSE22", "JOINT_NAMES", "build_body_model", "random_poses", "smpl_parents"]
