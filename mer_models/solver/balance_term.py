"""The balance term (``--balance``, opt-in): a motion whose mass could do what it shows (docs/model.md §Balance).

After the kinematic solve (and the physical terms), a few more whole-window Levenberg-Marquardt
iterations (:func:`~.ik.coupled_lm_ik`, same energy) add, per frame ``t``, residuals of the motion's own
dynamics (:mod:`mer_data.kinematics.dynamics`, unfiltered, without the bodies' spin: the centre of
mass' second difference, so a row reaches frames ``t - 1 .. t + 1`` only):

* **ZMP in the stance foot** (single-support frames of the kinematic solution): for each edge
  ``n . p + d <= 0`` of the stance foot's support polygon (:func:`mer_data.kinematics.support.stance_polygons`:
  its corners, read once per round, move with the foot's node), the excess
  ``relu(n . (c_xy f_z - c_z f_xy - (n_y, -n_x)) + (d + tol) f_z) / (M g)`` [m] (the ZMP's distance past
  the edge moved ``tol`` inward, written without the division by ``f_z``:
  where ``f_z = M g`` it is that distance; a pulling frame cannot hide behind ``f_z < 0``);
* **ballistic flight** (flight frames): ``f / (M g)`` (0 for a centre of mass in free fall).

Each row weighs ``weight * w_kp`` (flight ``flight_weight * w_kp``). What moves: everything the energy
lets move, at the energy's price; the key points are world positions, so the cheapest change is the
base's horizontal path (the stance foot's goal holds the foot; the legs take the difference) and the
torso's lean, and a temporal prior on the change from the kinematic solution (``change_smooth``, as the
constraint method's) keeps the change smooth. The Gauss-Newton product of a three-frame row couples
frames ``t - 1`` and ``t + 1``, which the block-tridiagonal solve does not hold: that block is replaced
by its bound ``2 a.c <= |a|^2 + |c|^2`` on the two frames' own blocks (a majoriser: each step still
lowers the cost it was computed for; the solver keeps a step only where the true cost fell).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import torch

from mer_data.kinematics.collision import shape_points
from mer_data.kinematics.dynamics import GRAVITY
from mer_data.kinematics.support import support_polygons
from mer_models.batch import batch_fk

from .ik import ancestors, coupled_lm_ik

__all__ = ["BalanceConfig", "BalanceInputs", "balance_rows", "MAX_CORNERS"]

MAX_CORNERS = 12  # corners of a stance polygon the term keeps (:func:`mer_data.kinematics.support.stance_polygons`)


@dataclasses.dataclass(frozen=True)
class BalanceConfig:
    """The balance term's weights and schedule (module docstring).

    weight: each ZMP row's weight relative to ``w_kp`` [1/m^2 of excess]; flight_weight: each flight
    row's; down: a foot is in the term's polygon only where its lowest vertex is this close to the floor [m]
    (the metric's 2 cm would let a solve lift a swing foot out of a polygon it relied on); tol: how far inside the stance foot's edges the ZMP is held [m]; rounds x iters: Levenberg-Marquardt
    iterations, the stance polygons re-read from the motion before each round; change_smooth: the prior on
    the change from the kinematic solution, relative to the solve's temporal prior.
    """

    weight: float = 30.0
    down: float | None = 0.01
    flight_weight: float = 3.0
    tol: float = 0.01
    rounds: int = 2
    iters: int = 6
    change_smooth: float = 1.0

    def __post_init__(self) -> None:
        for k in ("weight", "flight_weight", "tol", "change_smooth"):
            if not getattr(self, k) >= 0:
                raise ValueError(f"BalanceConfig.{k} must be >= 0, got {getattr(self, k)}")
        if self.rounds < 1 or self.iters < 1:
            raise ValueError(f"BalanceConfig.rounds and iters must be >= 1, got {self.rounds}, {self.iters}")


def balance_rows(x: torch.Tensor, mass: torch.Tensor, fps: float, verts: torch.Tensor, edges: torch.Tensor,
                 single: torch.Tensor, flight: torch.Tensor, tol: float) -> torch.Tensor:  # fmt: skip
    """The rows of one frame: (E + 3,) [1] (module docstring, unweighted).

    Args:
        x: (3, J, 3) the body centres of mass [m] at frames t - 1, t, t + 1; verts: (E, 3) the stance
            polygon's corners at frame t [m], counter-clockwise (seen from above), moving with the foot;
            edges: (E,) 1 for a real edge from corner e to e + 1, 0 for padding; single, flight: 0-d (0 or 1).
    """
    m = mass
    M = m.sum()
    g = x.new_tensor([0.0, 0.0, -GRAVITY])
    force_i = m[:, None] * ((x[0] - 2 * x[1] + x[2]) * fps**2 - g)  # (J, 3)
    f = force_i.sum(0)
    c = (m[:, None] * x[1]).sum(0) / M
    n = torch.linalg.cross(x[1] - c, force_i, dim=-1).sum(0)
    arm = c[:2] * f[2] - c[2] * f[:2] - torch.stack([n[1], -n[0]])  # f_z p
    v = verts[:, :2]
    e = torch.roll(v, -1, 0) - v
    normal = torch.stack([e[:, 1], -e[:, 0]], -1) / (e.norm(dim=-1, keepdim=True) + (1 - edges[:, None]) + 1e-12)
    d = -(normal * v).sum(-1)
    excess = torch.relu(normal @ arm + (d + tol) * f[2]) * edges / (M * GRAVITY)
    return torch.cat([excess * single, f / (M * GRAVITY) * flight])


class _Rows:
    """The term for one iteration of :func:`~.ik.coupled_lm_ik` (its ``physics`` interface)."""

    def __init__(self, inputs: "BalanceInputs", P: Any, w_kp: float) -> None:
        self.i, self.P = inputs, P
        dt, dev = P.dtype, P.dev
        J = P.J
        m = torch.zeros(J, dtype=dt, device=dev)
        k = min(J, len(inputs.mass))
        m[:k] = torch.tensor(inputs.mass[:k], dtype=dt, device=dev)
        self.mass = m
        self.com = torch.zeros(J, 3, dtype=dt, device=dev)
        self.com[:k] = torch.tensor(inputs.com[:k], dtype=dt, device=dev)
        c = inputs.cfg
        E = inputs.local.shape[-2]
        w = torch.cat([torch.full((E,), c.weight * w_kp), torch.full((3,), c.flight_weight * w_kp)]).to(dt).to(dev)
        self.sw = w.sqrt()
        self.single, self.flight = inputs.single.to(dt).to(dev), inputs.flight.to(dt).to(dev)
        self.node = inputs.node.to(dev)  # (B, T, E) each corner's node
        self.local = inputs.local.to(dt).to(dev)  # (B, T, E, 3) the corners in their node's frame
        self.edges = inputs.edges.to(dt).to(dev)
        E = self.local.shape[2]
        # [b, t, point, j]: joint j moves the point (a body's centre; a corner of the stance node)
        owner = torch.cat([torch.arange(J, device=dev).expand(*self.node.shape[:2], J), self.node], -1)
        mv = ancestors(P.graph.parents) | torch.eye(J, dtype=torch.bool, device=dev)  # (B, J, J)
        self.moves = torch.gather(mv[:, None].expand(-1, owner.shape[1], -1, -1), 2, owner[..., None].expand(*owner.shape, J)).to(dt)
        self.rows = torch.func.vmap(torch.func.jacrev(self._row, has_aux=True), in_dims=(0, 0, 0, 0))

    def _per_frame(self, sl):
        return [v[:, sl].flatten(0, 1) for v in (self.edges, self.single, self.flight)]

    def _x(self, pos, rot):
        """(B, T, J + E, 3): the body centres of mass, then the stance polygon's corners moved with their node."""
        com = pos + torch.einsum("btjxy,jy->btjx", rot, self.com)
        B, T = pos.shape[:2]
        bi = torch.arange(B, device=pos.device)[:, None]
        ti = torch.arange(T, device=pos.device)[None]
        bi, ti = bi[..., None], ti[..., None]
        corners = torch.einsum("btexy,btey->btex", rot[bi, ti, self.node], self.local) + pos[bi, ti, self.node]
        return torch.cat([com, corners], 2)

    def _row(self, x, edges, single, flight):
        J = self.mass.shape[0]
        r = balance_rows(x[:, :J], self.mass, self.i.fps, x[1, J:], edges, single, flight, self.i.cfg.tol) * self.sw
        return r, r

    def _rows_of(self, x):
        """Residuals (B, T, R) (0 at the two end frames) and their Jacobian (B, T, R, 3, J, 3) on x at t-1, t, t+1."""
        B, T = x.shape[:2]
        R = self.sw.shape[0]
        res = x.new_zeros(B, T, R)
        jac = x.new_zeros(B, T, R, 3, *x.shape[2:])
        if T < 3:
            return res, jac
        win = torch.stack([x[:, :-2], x[:, 1:-1], x[:, 2:]], 2).flatten(0, 1)  # (B (T-2), 3, J, 3)
        sl = slice(1, T - 1)
        jw, rw = self.rows(win, *self._per_frame(sl))
        res[:, sl] = rw.view(B, T - 2, R)
        jac[:, sl] = jw.view(B, T - 2, R, 3, *x.shape[2:])
        return res, jac

    def _dx(self, pos, rot, x):
        """(B, T, J, 3, n): each body centre's change per column (joints folded, base translation, world rotation)."""
        P = self.P
        a = (rot @ P.graph.axes.to(rot.dtype)[:, None, :, :, None])[..., 0]  # (B, T, J, 3) joint axes in the world
        arm = x[:, :, :, None] - pos[:, :, None]  # (B, T, Ji, Jj, 3)
        per = torch.linalg.cross(a[:, :, None].expand_as(arm), arm, dim=-1) * self.moves[..., None]
        jq = torch.einsum("btija,bjd->btiad", per, P.fold)
        eye = torch.eye(3, dtype=x.dtype, device=x.device)
        jt = eye.expand(*x.shape[:3], 3, 3)
        rel = x - pos[:, :, :1]
        jr = torch.linalg.cross(eye.expand(*x.shape[:3], 3, 3), rel[..., None, :].expand(*x.shape[:3], 3, 3), dim=-1).transpose(-1, -2)
        return torch.cat([jq, jt, jr], -1)

    # ---- the physics interface of coupled_lm_ik ---------------------------------------------------------
    def freeze(self, pos, rot, qd) -> dict:
        return {}

    def cost(self, pos, rot, qd, state) -> torch.Tensor:
        x = self._x(pos, rot)
        T = x.shape[1]
        out = x.new_zeros(x.shape[:2])
        if T < 3:
            return out
        win = torch.stack([x[:, :-2], x[:, 1:-1], x[:, 2:]], 2).flatten(0, 1)
        sl = slice(1, T - 1)
        f = torch.func.vmap(lambda *a: self._row(*a)[0])
        r = f(win, *self._per_frame(sl))
        out[:, sl] = (r**2).sum(-1).view(x.shape[0], T - 2)
        return out

    def linearise(self, pos, rot, qd, state):
        B, T = pos.shape[:2]
        n = self.P.n
        return pos.new_zeros(B, T, n, n), pos.new_zeros(B, T, n)

    def speed_terms(self, qd, cols):
        return None

    def speed_cost(self, qd, cols):
        return qd.new_zeros(qd.shape[:2])

    def coupled_terms(self, pos, rot, state):
        """Frames' blocks (B, T, n, n), the blocks coupling t + 1 to t (B, T-1, n, n) and ``J^T r`` (B, T, n)."""
        x = self._x(pos, rot)
        res, jac = self._rows_of(x)
        B, T = x.shape[:2]
        dx = self._dx(pos, rot, x).flatten(2, 3)  # (B, T, 3J, n)
        n = dx.shape[-1]
        h = pos.new_zeros(B, T, n, n)
        c = pos.new_zeros(B, max(T - 1, 0), n, n)
        g = pos.new_zeros(B, T, n)
        if T < 3:
            return h, c, g
        sl = slice(1, T - 1)
        blocks = [torch.einsum("btrk,btkn->btrn", jac[:, sl, :, k].flatten(-2), dx[:, k : T - 2 + k]) for k in range(3)]  # G_k on frame t-1+k
        a, b, cc = blocks
        r = res[:, sl]
        # the majoriser: 2 a.c dropped, |a|^2 and |c|^2 added once more to frames t-1 and t+1
        h[:, 0 : T - 2] += 2 * a.transpose(-1, -2) @ a
        h[:, 1 : T - 1] += b.transpose(-1, -2) @ b
        h[:, 2:T] += 2 * cc.transpose(-1, -2) @ cc
        c[:, 0 : T - 2] += b.transpose(-1, -2) @ a  # H[t, t-1]
        c[:, 1 : T - 1] += cc.transpose(-1, -2) @ b  # H[t+1, t]
        g[:, 0 : T - 2] += (a.transpose(-1, -2) @ r[..., None])[..., 0]
        g[:, 1 : T - 1] += (b.transpose(-1, -2) @ r[..., None])[..., 0]
        g[:, 2:T] += (cc.transpose(-1, -2) @ r[..., None])[..., 0]
        return h, c, g


@dataclasses.dataclass
class BalanceInputs:
    """The balance term of one batch (every sample the same robot): ``cfg``, the robot's node masses
    ``mass`` (J,) [kg] and centres of mass ``com`` (J, 3) in the node frames [m] (its
    :class:`~mer_data.robots.inertia.MassModel`), its collision model ``geometry``, the frame rate ``fps``.
    A round's support polygons (:meth:`solve` sets them): ``node`` (B, T, E) the node each corner moves
    with, ``local`` (B, T, E, 3) the corners in their node's frame, counter-clockwise, ``edges`` (B, T, E)
    which are real; ``single`` (B, T): frames with a polygon (every contact frame, single or double
    support), ``flight`` (B, T)."""

    cfg: BalanceConfig
    mass: np.ndarray
    com: np.ndarray
    geometry: Any
    fps: float = 30.0
    local: torch.Tensor | None = None
    edges: torch.Tensor | None = None
    single: torch.Tensor | None = None
    flight: torch.Tensor | None = None
    node: torch.Tensor | None = None

    @classmethod
    def of_robot(cls, robot: Any, cfg: BalanceConfig, fps: float, geometry: Any = None) -> "BalanceInputs":
        from mer_data.robots.collision import collision_model
        from mer_data.robots.inertia import mass_model

        mm = mass_model(robot)
        return cls(cfg, np.asarray(mm.mass, np.float64), np.asarray(mm.com, np.float64),
                   collision_model(robot) if geometry is None else geometry, fps)  # fmt: skip

    def build(self, P: Any, w_kp: float) -> _Rows:
        return _Rows(self, P, w_kp)

    def read_support(self, pos: torch.Tensor, rot: torch.Tensor) -> None:
        """This round's stance polygons and flight frames from node frames (B, T, J, 3), (B, T, J, 3, 3)."""
        J = len(self.mass)
        p, r = pos[..., :J, :].double().cpu(), rot[..., :J, :, :].double().cpu()
        verts = shape_points(self.geometry, p, r, "vertices").numpy()
        B, T = verts.shape[:2]
        E = MAX_CORNERS
        local, edges = np.zeros((B, T, E, 3)), np.zeros((B, T, E))
        node, kind = np.zeros((B, T, E), np.int64), np.zeros((B, T), np.int64)
        has = np.zeros((B, T), bool)
        for b in range(B):
            kind[b], nodes, corners = support_polygons(self.geometry, verts[b], E, down=self.cfg.down)
            for t in range(T):
                if corners[t] is None:
                    continue
                k = len(corners[t])
                n = nodes[t]
                pr, rr = p[b, t, n].numpy(), r[b, t, n].numpy()  # (k, 3), (k, 3, 3)
                local[b, t, :k] = np.einsum("kab,ka->kb", rr, corners[t] - pr)
                local[b, t, k:], node[b, t, :k], node[b, t, k:] = local[b, t, k - 1], n, n[-1]
                edges[b, t, :k], has[b, t] = 1, True
        self.local, self.edges, self.node = torch.from_numpy(local), torch.from_numpy(edges), torch.from_numpy(node).to(pos.device)
        self.single, self.flight = torch.from_numpy(has), torch.from_numpy(kind == 0)

    def solve(self, cfg: Any, graph: Any, eta: torch.Tensor, goal: torch.Tensor, q: torch.Tensor, base_pos: torch.Tensor,
              base_rot: torch.Tensor, *, smooth: float, tol: float, goal_rot: torch.Tensor | None = None,
              rot_mask: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:  # fmt: skip
        """The term's rounds after a solve (module docstring): ``q`` (B, T, J), ``base_pos`` (B, T, 3),
        ``base_rot`` (B, T, 3, 3) in, the balanced motion out (arguments as :func:`~.ik.coupled_lm_ik`)."""
        plain = q
        for _ in range(self.cfg.rounds):
            self.read_support(*batch_fk(graph, q, base_pos, base_rot))
            if not bool(self.single.any() or self.flight.any()):
                break
            import time, logging
            from .ik import _Problem
            PP = _Problem(cfg, graph, eta, goal, q, goal_rot, rot_mask)
            pos, rot = batch_fk(graph, q, base_pos, base_rot)
            print("DBG before", float(self.build(PP, cfg.w_kp).cost(pos, rot, None, {}).sum()))
            t0 = time.perf_counter()
            st = {}
            q, base_pos, base_rot = coupled_lm_ik(cfg, graph, eta, goal, q, base_pos, base_rot, iters=self.cfg.iters, smooth=smooth,
                                                  tol=tol, physics=self, change_of=plain, change_smooth=smooth * self.cfg.change_smooth,
                                                  goal_rot=goal_rot, rot_mask=rot_mask, stats=st)  # fmt: skip
            pos, rot = batch_fk(graph, q, base_pos, base_rot)
            print("DBG round", time.perf_counter() - t0, st["iterations"], float(st["cost"].sum()), "single", int(self.single.sum()), "bal cost", float(self.build(PP, cfg.w_kp).cost(pos, rot, None, {}).sum()))
        return q, base_pos, base_rot
