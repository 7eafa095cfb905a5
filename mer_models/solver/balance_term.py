"""The balance term (``--balance``, opt-in): a motion whose mass could do what it shows (docs/model.md §Balance).

Two methods (:attr:`BalanceConfig.method`). **``path``** (the default, :mod:`.balance_path`): each round
corrects the centre of mass's horizontal path over the whole window by a banded least-squares problem
(the ZMP of the metric, linear in that path, held in the support polygon, flight frames ballistic) and
the whole body's height (hovering feet put down, jumps ballistic), moves every key-point goal above the
feet with the first and every goal with the second and runs ``iters`` whole-window Levenberg-Marquardt iterations
(with the solve's physical terms, the floor and joint speed ``physics_gain`` x harder): it moves the base's
horizontal path and the body above the legs, the legs taking up the difference. **``rows``** (the first
attempt, kept for comparison; docs/decisions.md §The balance term), below:

after the kinematic solve (and the physical terms), :attr:`BalanceConfig.rounds` rounds of whole-window
Levenberg-Marquardt iterations (:func:`~.ik.coupled_lm_ik`, the same energy) add, per frame ``t``,
residuals of the motion's own dynamics as the balance metric measures them
(:mod:`mer_data.kinematics.dynamics`: second differences of every body's centre of mass, the metric's
one 5-tap binomial filter; the bodies' spin left out), so a row reaches frames ``t - 3 .. t + 3``:

* **ZMP in the support polygon** (every contact frame): for each edge ``n . p + d <= 0`` of the
  polygon (:func:`mer_data.kinematics.support.support_polygons`, read at a round's start; each corner
  moves with its node, so moving a foot moves its edges; a foot counts only while its lowest vertex
  is within ``down`` of the floor), the excess ``relu(n . p + d + tol)`` [m] of the ZMP
  ``p = (c_xy f_z - c_z f_xy - (n_y, -n_x)) / max(f_z, 0.2 M g)`` past the edge moved ``tol`` inward
  (written with ``f_z`` multiplied out, the solve lowered ``f_z`` instead: a sagging centre of mass
  scales the excess down without moving the ZMP);
* **ballistic flight** (flight frames): ``f / (M g)`` (0 for a centre of mass in free fall);
* **the support held** (contact frames): each polygon corner's displacement from where the round read
  it (without these rows the solve moved the polygon under the ZMP, tilting or sliding the stance foot,
  instead of the ZMP over the polygon).

Each row weighs ``weight * w_kp`` (flight ``flight_weight * w_kp``, held corners ``hold_weight * w_kp``).
What moves: the rows see every column (joints, base translation and rotation) and the energy picks the
cheapest change; with the support held and the key points' goals in the world, that is the base's path
with the legs taking up the difference, and the lean of the torso and arms. A temporal prior on the
change from the kinematic solution (``change_smooth``, as the constraint method's) keeps it smooth. The unfiltered three-frame rows were tried first: the solve met them with frame-to-frame
alternating accelerations that the metric's filter averages away (its single-support ZMP stayed
outside; docs/decisions.md). The Gauss-Newton product of a seven-frame row couples frames up to six
apart, which the block-tridiagonal solve does not hold: each product of two frames two or more apart is
replaced by its bound ``2 a.b <= |a|^2 + |b|^2`` on the frames' own blocks (a majoriser: its step
lowers the cost it was computed for; the solver keeps a step only where the true cost fell).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import torch

from mer_data.kinematics.collision import shape_points
from mer_data.kinematics.dynamics import BINOMIAL, GRAVITY
from mer_data.kinematics.support import support_polygons
from mer_models.batch import batch_fk

from .balance_path import solve_path
from .ik import ancestors, coupled_lm_ik

__all__ = ["BalanceConfig", "BalanceInputs", "balance_rows", "MAX_CORNERS"]

MIN_FZ = 0.2  # the ZMP's division by f_z never below this share of the weight
HALF = 3  # a row reaches frames t - HALF .. t + HALF (the filter's 5 taps over second differences)
MAX_CORNERS = 12  # corners of a support polygon the term keeps (:func:`mer_data.kinematics.support.support_polygons`)


@dataclasses.dataclass(frozen=True)
class BalanceConfig:
    """The balance term's weights and schedule (module docstring).

    weight: each ZMP row's weight relative to ``w_kp`` [1/m^2 of excess]; hold_weight: each held corner
    coordinate's; flight_weight: each flight row's; down: a foot is in the term's polygon only where its
    lowest vertex is this close to the floor [m] (with the metric's 2 cm a solve lifted a swing foot out
    of a polygon it relied on); tol: how far inside the polygon's edges the ZMP is held [m]; rounds x
    iters: Levenberg-Marquardt iterations, the polygons read from the motion before each round;
    change_smooth: the prior on the change from the kinematic solution, relative to the solve's
    temporal prior (``rows``). method: ``path`` or ``rows`` (module docstring); margin: how far inside the
    support polygon the path correction puts the ZMP [m]; path_smooth: the weight of the correction's
    filtered acceleration (in ZMP units, ``c_z / g`` times it) against its size; physics_gain: the
    solve's floor and joint-speed terms this much harder in the ``path`` rounds (0: without the physical terms);
    hover: the ``path`` rounds also move the whole body vertically (:func:`~.balance_path.vertical_correction`):
    a flight phase whose lowest point stays below ``hover`` [m] is put down on the floor, any other made
    ballistic (None: no vertical correction); top: how high [m] the lowest point of a contact frame may end.
    """

    weight: float = 30.0
    hold_weight: float = 100.0
    down: float | None = 0.01
    flight_weight: float = 3.0
    tol: float = 0.01
    rounds: int = 6
    iters: int = 6
    change_smooth: float = 1.0
    method: str = "path"
    margin: float = 0.01
    path_smooth: float = 0.1
    physics_gain: float = 3.0
    hover: float | None = 0.05
    top: float = 0.012

    def __post_init__(self) -> None:
        for k in ("weight", "hold_weight", "flight_weight", "tol", "change_smooth"):
            if not getattr(self, k) >= 0:
                raise ValueError(f"BalanceConfig.{k} must be >= 0, got {getattr(self, k)}")
        if self.down is not None and not self.down > 0:
            raise ValueError(f"BalanceConfig.down must be > 0 or None, got {self.down}")
        if self.method not in ("path", "rows"):
            raise ValueError(f"BalanceConfig.method must be 'path' or 'rows', got {self.method!r}")
        if self.hover is not None and not self.hover > 0:
            raise ValueError(f"BalanceConfig.hover must be > 0 or None, got {self.hover}")
        if not 0 < self.top < 0.02:
            raise ValueError(f"BalanceConfig.top must be in (0, 0.02) m (the support's 2 cm), got {self.top}")
        if self.rounds < 1 or self.iters < 1:
            raise ValueError(f"BalanceConfig.rounds and iters must be >= 1, got {self.rounds}, {self.iters}")


def balance_rows(x: torch.Tensor, mass: torch.Tensor, fps: float, verts: torch.Tensor, edges: torch.Tensor,
                 contact: torch.Tensor, flight: torch.Tensor, tol: float, read: torch.Tensor) -> torch.Tensor:  # fmt: skip
    """The rows of one frame: (E + 3 + 3 E,) (module docstring, unweighted): the ZMP's excess per edge [m],
    the flight force [1], each corner's displacement from where the round read it [m].

    Args:
        x: (7, J, 3) the body centres of mass [m] at frames t - 3 .. t + 3; verts: (E, 3) the support
            polygon's corners at frame t [m], counter-clockwise (seen from above), moving with their nodes;
            edges: (E,) 1 for a real edge from corner e to e + 1, 0 for padding; contact, flight: 0-d
            (0 or 1); read: (E, 3) the corners where the round read them [m].
    """
    m = mass
    M = m.sum()
    g = x.new_tensor([0.0, 0.0, -GRAVITY])
    acc = (x[:-2] - 2 * x[1:-1] + x[2:]) * fps**2  # (5, J, 3) at frames t - 2 .. t + 2
    w = x.new_tensor(BINOMIAL) / sum(BINOMIAL)
    force_i = m[:, None] * ((w[:, None, None] * acc).sum(0) - g)  # (J, 3): the metric's filter
    f = force_i.sum(0)
    xt = x[HALF]
    c = (m[:, None] * xt).sum(0) / M
    n = torch.linalg.cross(xt - c, force_i, dim=-1).sum(0)
    arm = c[:2] * f[2] - c[2] * f[:2] - torch.stack([n[1], -n[0]])  # f_z p
    v = verts[:, :2]
    e = torch.roll(v, -1, 0) - v
    normal = torch.stack([e[:, 1], -e[:, 0]], -1) / (e.norm(dim=-1, keepdim=True) + (1 - edges[:, None]) + 1e-12)
    d = -(normal * v).sum(-1)
    p = arm / f[2].clamp_min(MIN_FZ * M * GRAVITY)  # the ZMP (f_z held away from 0: flight and pulling are other rows)
    excess = torch.relu(normal @ p + d + tol) * edges
    held = ((verts - read) * edges[:, None] * contact).flatten()
    return torch.cat([excess * contact, f / (M * GRAVITY) * flight, held])


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
        w = torch.cat([torch.full((E,), c.weight * w_kp), torch.full((3,), c.flight_weight * w_kp),
                       torch.full((3 * E,), c.hold_weight * w_kp)]).to(dt).to(dev)  # fmt: skip
        self.sw = w.sqrt()
        self.contact, self.flight = inputs.contact.to(dt).to(dev), inputs.flight.to(dt).to(dev)
        self.node = inputs.node.to(dev)  # (B, T, E) each corner's node
        self.local = inputs.local.to(dt).to(dev)  # (B, T, E, 3) the corners in their node's frame
        self.edges = inputs.edges.to(dt).to(dev)
        self.read = inputs.read.to(dt).to(dev)
        E = self.local.shape[2]
        # [b, t, point, j]: joint j moves the point (a body's centre; a corner of the stance node)
        owner = torch.cat([torch.arange(J, device=dev).expand(*self.node.shape[:2], J), self.node], -1)
        mv = ancestors(P.graph.parents) | torch.eye(J, dtype=torch.bool, device=dev)  # (B, J, J)
        self.moves = torch.gather(mv[:, None].expand(-1, owner.shape[1], -1, -1), 2, owner[..., None].expand(*owner.shape, J)).to(
            dt
        )
        self.rows = torch.func.vmap(torch.func.jacrev(self._row, has_aux=True), in_dims=(0, 0, 0, 0, 0))

    def _per_frame(self, sl):
        return [v[:, sl].flatten(0, 1) for v in (self.edges, self.contact, self.flight, self.read)]

    def _x(self, pos, rot):
        """(B, T, J + E, 3): the body centres of mass, then the stance polygon's corners moved with their node."""
        com = pos + torch.einsum("btjxy,jy->btjx", rot, self.com)
        B, T = pos.shape[:2]
        bi = torch.arange(B, device=pos.device)[:, None]
        ti = torch.arange(T, device=pos.device)[None]
        bi, ti = bi[..., None], ti[..., None]
        corners = torch.einsum("btexy,btey->btex", rot[bi, ti, self.node], self.local) + pos[bi, ti, self.node]
        return torch.cat([com, corners], 2)

    def _row(self, x, edges, contact, flight, read):
        J = self.mass.shape[0]
        r = balance_rows(x[:, :J], self.mass, self.i.fps, x[HALF, J:], edges, contact, flight, self.i.cfg.tol, read) * self.sw
        return r, r

    def _windows(self, x):
        """(B (T - 2 HALF), 2 HALF + 1, P, 3) every interior frame's window, and the interior's slice."""
        T, W = x.shape[1], 2 * HALF + 1
        return torch.stack([x[:, k : T - W + 1 + k] for k in range(W)], 2).flatten(0, 1), slice(HALF, T - HALF)

    def _rows_of(self, x):
        """Residuals (B, T, R) (0 at the HALF end frames) and their Jacobian (B, T, R, W, P, 3) on the window's points."""
        B, T = x.shape[:2]
        R, W = self.sw.shape[0], 2 * HALF + 1
        res = x.new_zeros(B, T, R)
        jac = x.new_zeros(B, T, R, W, *x.shape[2:])
        if T < W:
            return res, jac
        win, sl = self._windows(x)
        jw, rw = self.rows(win, *self._per_frame(sl))
        res[:, sl] = rw.view(B, T - W + 1, R)
        jac[:, sl] = jw.view(B, T - W + 1, R, W, *x.shape[2:])
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
        jr = torch.linalg.cross(eye.expand(*x.shape[:3], 3, 3), rel[..., None, :].expand(*x.shape[:3], 3, 3), dim=-1).transpose(
            -1, -2
        )
        return torch.cat([jq, jt, jr], -1)

    # ---- the physics interface of coupled_lm_ik ---------------------------------------------------------
    def freeze(self, pos, rot, qd) -> dict:
        return {}

    def cost(self, pos, rot, qd, state) -> torch.Tensor:
        x = self._x(pos, rot)
        out = x.new_zeros(x.shape[:2])
        if x.shape[1] < 2 * HALF + 1:
            return out
        win, sl = self._windows(x)
        r = torch.func.vmap(lambda *a: self._row(*a)[0])(win, *self._per_frame(sl))
        out[:, sl] = (r**2).sum(-1).view(x.shape[0], -1)
        return out

    def linearise(self, pos, rot, qd, state, with_cost: bool = False):
        """No per-frame blocks (the rows couple frames: :meth:`coupled_terms`); ``with_cost`` also
        :meth:`cost` (B, T), as the physical terms' interface returns it."""
        B, T = pos.shape[:2]
        n = self.P.n
        h, g = pos.new_zeros(B, T, n, n), pos.new_zeros(B, T, n)
        return (h, g, self.cost(pos, rot, qd, state)) if with_cost else (h, g)

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
        W = 2 * HALF + 1
        if T < W:
            return h, c, g
        sl = slice(HALF, T - HALF)
        r = res[:, sl, :, None]
        G = [
            torch.einsum("btrk,btkn->btrn", jac[:, sl, :, k].flatten(-2), dx[:, k : T - W + 1 + k]) for k in range(W)
        ]  # on frame t - HALF + k
        for k in range(W):  # the majoriser: 2 a_i . a_j of frames two or more apart dropped, |a_i|^2 + |a_j|^2 added
            far = W - 1 - (k > 0) - (k < W - 1)
            f = slice(k, T - W + 1 + k)
            h[:, f] += (1 + far) * G[k].transpose(-1, -2) @ G[k]
            g[:, f] += (G[k].transpose(-1, -2) @ r)[..., 0]
            if k + 1 < W:
                c[:, f] += G[k + 1].transpose(-1, -2) @ G[k]  # H[t - HALF + k + 1, t - HALF + k]
        return h, c, g


@dataclasses.dataclass
class BalanceInputs:
    """The balance term of one batch (every sample the same robot): ``cfg``, the robot's node masses
    ``mass`` (J,) [kg] and centres of mass ``com`` (J, 3) in the node frames [m] (its
    :class:`~mer_data.robots.inertia.MassModel`), its collision model ``geometry``, the frame rate ``fps``.
    A round's support polygons (:meth:`solve` sets them): ``node`` (B, T, E) the node each corner moves
    with, ``local`` (B, T, E, 3) the corners in their node's frame, counter-clockwise, ``edges`` (B, T, E)
    which are real; ``contact`` (B, T): frames with a polygon (every contact frame, single or double
    support), ``flight`` (B, T)."""

    cfg: BalanceConfig
    mass: np.ndarray
    com: np.ndarray
    geometry: Any
    fps: float = 30.0
    local: torch.Tensor | None = None
    read: torch.Tensor | None = None
    edges: torch.Tensor | None = None
    contact: torch.Tensor | None = None
    flight: torch.Tensor | None = None
    node: torch.Tensor | None = None
    model: Any = None

    @classmethod
    def of_robot(cls, robot: Any, cfg: BalanceConfig, fps: float, geometry: Any = None) -> "BalanceInputs":
        from mer_data.robots.collision import collision_model
        from mer_data.robots.inertia import mass_model

        mm = mass_model(robot)
        return cls(cfg, np.asarray(mm.mass, np.float64), np.asarray(mm.com, np.float64),
                   collision_model(robot) if geometry is None else geometry, fps, model=mm)  # fmt: skip

    def build(self, P: Any, w_kp: float) -> _Rows:
        return _Rows(self, P, w_kp)

    def read_support(self, pos: torch.Tensor, rot: torch.Tensor) -> None:
        """This round's stance polygons and flight frames from node frames (B, T, J, 3), (B, T, J, 3, 3)."""
        J = len(self.mass)
        p, r = pos[..., :J, :].double().cpu(), rot[..., :J, :, :].double().cpu()
        verts = shape_points(self.geometry, p, r, "vertices").numpy()
        B, T = verts.shape[:2]
        E = MAX_CORNERS
        local, edges, read = np.zeros((B, T, E, 3)), np.zeros((B, T, E)), np.zeros((B, T, E, 3))
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
                read[b, t, :k], read[b, t, k:] = corners[t], corners[t][-1]
                edges[b, t, :k], has[b, t] = 1, True
        self.local, self.edges, self.node = (
            torch.from_numpy(local),
            torch.from_numpy(edges),
            torch.from_numpy(node).to(pos.device),
        )
        self.read = torch.from_numpy(read)
        self.contact, self.flight = torch.from_numpy(has), torch.from_numpy(kind == 0)

    def solve(self, cfg: Any, graph: Any, eta: torch.Tensor, goal: torch.Tensor, q: torch.Tensor, base_pos: torch.Tensor,
              base_rot: torch.Tensor, *, smooth: float, tol: float, goal_rot: torch.Tensor | None = None,
              rot_mask: torch.Tensor | None = None, physics: Any = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:  # fmt: skip
        """The term's rounds after a solve (module docstring): ``q`` (B, T, J), ``base_pos`` (B, T, 3),
        ``base_rot`` (B, T, 3, 3) in, the balanced motion out (arguments as :func:`~.ik.coupled_lm_ik`)."""
        if self.cfg.method == "path":
            return solve_path(self, cfg, graph, eta, goal, q, base_pos, base_rot, smooth=smooth, tol=tol, goal_rot=goal_rot,
                              rot_mask=rot_mask, physics=physics)  # fmt: skip
        plain = q
        for _ in range(self.cfg.rounds):
            self.read_support(*batch_fk(graph, q, base_pos, base_rot))
            if not bool(self.contact.any() or self.flight.any()):
                break
            q, base_pos, base_rot = coupled_lm_ik(cfg, graph, eta, goal, q, base_pos, base_rot, iters=self.cfg.iters, smooth=smooth,
                                                  tol=tol, physics=self, change_of=plain, change_smooth=smooth * self.cfg.change_smooth,
                                                  goal_rot=goal_rot, rot_mask=rot_mask)  # fmt: skip
        return q, base_pos, base_rot
