"""Penetration depths of convex polytopes against MuJoCo's collision on the same hulls (the oracle),
and the floor's lowest points against the vertices themselves."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from mer_data.kinematics.collision import lowest_points, pair_depths
from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_data.robots.collision import polytope
from mer_data.robots.hulls import simplify_hull

mujoco = pytest.importorskip("mujoco")


def _pad(x: np.ndarray, n: int) -> np.ndarray:
    return np.concatenate([x, np.repeat(x[:1], n - len(x), 0)])


def _model(*hulls: np.ndarray) -> SimpleNamespace:
    polys = [polytope(h) for h in hulls]
    P, F, V = (max(len(p[i]) for p in polys) for i in (2, 1, 0))
    centers = [(v.max(0) + v.min(0)) / 2 for v, _, _ in polys]
    return SimpleNamespace(
        node=np.arange(len(hulls)), points=np.stack([_pad(p[2], P) for p in polys]),
        planes=np.stack([_pad(p[1], F) for p in polys]), vertices=np.stack([_pad(p[0], V) for p in polys]),
        center=np.stack(centers), radius=np.array([np.linalg.norm(p[0] - c, axis=1).max() for p, c in zip(polys, centers)]),
        pairs=np.array([[0, 1]]),
    )  # fmt: skip


def _quat(r: np.ndarray) -> np.ndarray:
    out = np.zeros(4)
    mujoco.mju_mat2Quat(out, r.reshape(-1))
    return out


def _pushed_pairs(seed: int, n: int, deepest: float):
    """``n`` random pairs of 48-vertex hulls, the second pushed 0-``deepest`` [m] into the first along
    a random direction (found by bisection on MuJoCo's own contact): ``(model, pos (1, 2, 3), rot
    (1, 2, 3, 3), MuJoCo's depth (GJK/EPA on the hulls))`` each."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        ha = simplify_hull(rng.normal(size=(300, 3)) * [0.1, 0.04, 0.03], 48)[0]
        hb = simplify_hull(rng.normal(size=(300, 3)) * [0.05, 0.06, 0.04], 48)[0]
        m = _model(ha, hb)
        rot = axis_angle_to_matrix(torch.from_numpy(rng.normal(size=(2, 3)))).numpy()
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        va, vb = (" ".join(map(str, v.ravel())) for v in (polytope(ha)[0], polytope(hb)[0]))
        xml = (f'<mujoco><asset><mesh name="a" vertex="{va}"/><mesh name="b" vertex="{vb}"/></asset><worldbody>'
               '<body><freejoint/><geom type="mesh" mesh="a"/></body><body><freejoint/><geom type="mesh" mesh="b"/></body>'
               "</worldbody></mujoco>")  # fmt: skip
        mm = mujoco.MjModel.from_xml_string(xml)
        dd = mujoco.MjData(mm)

        def mj_depth(x: float) -> float:
            dd.qpos[:] = np.concatenate([[0, 0, 0], _quat(rot[0]), d * x, _quat(rot[1])])
            mujoco.mj_forward(mm, dd)
            return -min((dd.contact[i].dist for i in range(dd.ncon)), default=1.0)

        lo, hi = 0.0, 1.0
        for _ in range(40):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if mj_depth(mid) > 0 else (lo, mid)
        x = hi - rng.uniform(0.0, deepest)
        yield m, torch.from_numpy(np.stack([np.zeros(3), d * x]))[None], torch.from_numpy(rot)[None], mj_depth(x)


def test_penetration_depth_agrees_with_mujoco_on_shallow_contacts():
    """60 random pairs of 48-vertex hulls pushed 0-30 mm into each other along a random direction
    (found by bisection on MuJoCo's own contact): our depth against MuJoCo's (GJK/EPA on the hulls)."""
    ours, theirs = [], []
    for m, pos, rot, mj in _pushed_pairs(7, 60, 0.03):
        theirs.append(mj)
        ours.append(float(pair_depths(m, pos, rot)[0, 0]))
    ours_a, theirs_a = np.array(ours), np.array(theirs)
    err = np.abs(ours_a - theirs_a)
    assert theirs_a.max() > 0.015 and theirs_a.min() >= 0  # the range the metrics' 1 cm threshold lives in
    assert np.median(err) < 0.0015 and np.percentile(err, 90) < 0.004, (np.median(err), np.percentile(err, 90))
    assert ((ours_a > 0.01) == (theirs_a > 0.01)).mean() >= 0.9


def test_apart_pairs_are_negative_and_far_pairs_skip_the_exact_test():
    cube = np.array([[x, y, z] for x in (-0.05, 0.05) for y in (-0.05, 0.05) for z in (-0.05, 0.05)])
    m = _model(cube, cube)
    eye = torch.eye(3, dtype=torch.float64).expand(1, 2, 3, 3)
    for gap, want in ((0.12, -0.02), (1.0, None), (0.08, 0.02)):
        d = float(pair_depths(m, torch.tensor([[[0.0, 0, 0], [gap, 0, 0]]], dtype=torch.float64), eye)[0, 0])
        if want is None:
            assert d < -0.5
        else:
            assert d == pytest.approx(want, abs=1e-9)


def test_lowest_points_are_the_lowest_vertices():
    rng = np.random.default_rng(3)
    h = simplify_hull(rng.normal(size=(100, 3)) * 0.1, 32)[0]
    m = _model(h, h + 1.0)
    r = axis_angle_to_matrix(torch.from_numpy(rng.normal(size=(4, 2, 3))))
    t = torch.from_numpy(rng.normal(size=(4, 2, 3)))
    z, idx = lowest_points(m, t, r)
    world = torch.einsum("fsij,svj->fsvi", r, torch.from_numpy(m.vertices)) + t[:, :, None]
    assert torch.allclose(z, world[..., 2].min(-1).values)


def test_where_computes_only_the_entries_asked_for():
    """``where`` leaves the other (frame, pair) entries at -inf and the asked ones as without it."""
    cube = np.array([[x, y, z] for x in (-0.05, 0.05) for y in (-0.05, 0.05) for z in (-0.05, 0.05)])
    m = _model(cube, cube)
    gaps = torch.tensor([0.08, 0.12, 0.09, 0.5], dtype=torch.float64)  # 2 cm in, 2 cm apart, 1 cm in, far
    pos = torch.zeros(4, 2, 3, dtype=torch.float64)
    pos[:, 1, 0] = gaps
    eye = torch.eye(3, dtype=torch.float64).expand(4, 2, 3, 3)
    full = pair_depths(m, pos, eye)
    where = torch.tensor([[True], [False], [True], [False]])
    part = pair_depths(m, pos, eye, where=where)
    assert torch.equal(part[where], full[where]) and bool(torch.isinf(part[~where]).all()) and bool((part[~where] < 0).all())
    assert float(full[0, 0]) == pytest.approx(0.02, abs=1e-9) and float(full[2, 0]) == pytest.approx(0.01, abs=1e-9)


def test_the_separating_axis_depth_bounds_the_true_depth_from_above():
    """``which="sat"`` (the solver's depth) against MuJoCo's GJK/EPA depth and the metrics' sample
    point depth, on 40 random hull pairs pushed 0-40 mm into each other: never below either (so a
    solver holding it under a margin holds the metric there too), and equal to MuJoCo's where the
    deepest contact is face against vertex (the median)."""
    sat, pts, mj = [], [], []
    for m, pos, r, depth in _pushed_pairs(11, 40, 0.04):
        mj.append(depth)
        sat.append(float(pair_depths(m, pos, r, which="sat")[0, 0]))
        pts.append(float(pair_depths(m, pos, r)[0, 0]))
    sat_a, pts_a, mj_a = np.array(sat), np.array(pts), np.array(mj)
    assert mj_a.max() > 0.02
    assert (sat_a >= pts_a - 1e-9).all()
    assert (sat_a >= mj_a - 2e-4).all(), (sat_a - mj_a).min()  # MuJoCo's depth is exact to its own tolerance
    assert np.median(sat_a - mj_a) < 0.002


def test_the_separating_axis_of_side_by_side_feet_points_across():
    """Two 20 x 8 x 5 cm feet side by side, overlapping 3 cm across (and 19 cm along, 5 cm up):
    the separating axis is across (y), and its depth is the 3 cm overlap."""
    from mer_data.kinematics.collision import contact_points

    box = np.array([[x, y, z] for x in (-0.1, 0.1) for y in (-0.04, 0.04) for z in (0.0, 0.05)])
    m = _model(box, box)
    pos = torch.tensor([[[0.0, 0.0, 0.0], [0.01, 0.05, 0.0]]], dtype=torch.float64)
    rot = torch.eye(3, dtype=torch.float64).expand(1, 2, 3, 3)
    assert float(pair_depths(m, pos, rot, which="sat")[0, 0]) == pytest.approx(0.03)
    entries = tuple(torch.tensor([v]) for v in (0, 0, 0, 0, 1))
    depth, point, normal, _, _ = contact_points(m, pos[:, None], rot[:, None], entries, 1, "sat")
    assert float(depth[0, 0, 0]) == pytest.approx(0.03)
    assert abs(float(normal[0, 0, 0, 1])) == pytest.approx(1.0)


def test_shapes_of_different_sizes_are_computed_without_their_padding_and_the_same():
    """A box (8 vertices), a 24-vertex prism and a 48-vertex hull in one model: every pair's depth,
    computed by size class with each class's arrays cut to its largest, equals the computation over
    the whole padded arrays (``_inside`` directly), in every mode."""
    from mer_data.kinematics.collision import _inside, _separating

    rng = np.random.default_rng(3)
    box = np.array([[x, y, z] for x in (-0.1, 0.1) for y in (-0.04, 0.04) for z in (0.0, 0.05)])
    ang = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    prism = np.concatenate([np.stack([0.05 * np.cos(ang), 0.05 * np.sin(ang), np.full(12, z)], 1) for z in (-0.1, 0.1)])
    hull = simplify_hull(rng.normal(size=(300, 3)) * [0.08, 0.05, 0.06], 48)[0]
    m = _model(box, prism, hull)
    m.pairs = np.array([[0, 1], [0, 2], [1, 2]])
    F = 64
    pos = torch.from_numpy(rng.normal(size=(F, 3, 3)) * 0.06)
    rot = axis_angle_to_matrix(torch.from_numpy(rng.normal(size=(F, 3, 3))))
    node = torch.arange(3)
    f = torch.arange(F).repeat_interleave(3)
    sa, sb = torch.tensor([0, 0, 1]).repeat(F), torch.tensor([1, 2, 2]).repeat(F)
    verts, pts, planes = (torch.from_numpy(getattr(m, k)) for k in ("vertices", "points", "planes"))
    gap = torch.maximum(_inside(verts, planes, node, pos, rot, f, sa, sb, gap=True), _inside(verts, planes, node, pos, rot, f, sb, sa, gap=True))
    deep = torch.maximum(_inside(pts, planes, node, pos, rot, f, sa, sb), _inside(pts, planes, node, pos, rot, f, sb, sa))
    sat = torch.minimum(_separating(verts, planes, node, pos, rot, f, sa, sb)[0], _separating(verts, planes, node, pos, rot, f, sb, sa)[0])
    assert torch.allclose(sat, -gap)
    close = (gap <= 0).reshape(F, 3)
    assert close.any() and (~close).any()  # both kinds of entries
    got = pair_depths(m, pos, rot, margin=1.0)  # margin: every pair computed exactly
    want = torch.where(close, deep.reshape(F, 3), -gap.reshape(F, 3))
    assert torch.allclose(got, want, atol=1e-12)
    assert torch.allclose(pair_depths(m, pos, rot, margin=1.0, which="sat"), -gap.reshape(F, 3), atol=1e-12)
