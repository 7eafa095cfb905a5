"""Physical terms of the optimiser: what keeps a retargeted motion trainable for a tracking policy.

Residual rows added to the Levenberg-Marquardt steps of :mod:`mer_models.solver.ik`, per frame, on
the target's collision polytopes (:mod:`mer_data.robots.collision`), floor at z = 0:

* **floor** ``w_floor``: every shape's lowest vertices (:data:`FLOOR_VERTICES`) at or above the
  floor (one-sided);
* **stance** (the source's foot down, :func:`mer_data.motion.contacts.foot_contacts`): the foot's
  lowest point on the floor (``w_stance``), the foot flat (its node frame's z axis vertical,
  ``w_flat``: every robot's zero pose stands on flat feet) and put (its node's x, y at the mean of
  that stance phase, ``w_anchor``);
* **swing** (the source's foot up): the foot's lowest point at least ``swing_clearance`` up
  (one-sided, ``w_swing``);
* **self-penetration** ``w_self``: each interpenetrating pair of checked bodies pushed apart to
  ``self_margin`` along its separating axis, the one of least overlap (:data:`SELF_POINTS`,
  :func:`mer_data.kinematics.collision.pair_contacts`): its depth bounds the metric's from above;
* **joint speed** ``w_speed``: ``|q_{t+1} - q_t|`` at most ``speed_fraction`` of the URDF velocity
  limit per frame (one-sided), in the whole-window solver only (:func:`~.ik.coupled_lm_ik`), whose
  block-tridiagonal system couples the frames exactly (:meth:`Physics.speed_terms`).

With ``lock_blend`` >= 0, before the solve, the position goals of each stance foot's sole points
are held at their stance phase's mean x, y (:meth:`PhysicsInputs.lock_goals`, blended over
``lock_blend`` frames): the goals of a planted foot do not slide; and the feet's goals are kept
the target's foot width apart (:meth:`PhysicsInputs.separate_feet`). With ``self_repair_iters`` > 0
the self term runs only after the solve, on the samples and pairs it left interpenetrating, and
on frames within ``repair_reach`` of where they do (and of where a body other than a foot is on
the floor), the other frames held, with the temporal prior ``repair_smooth`` times stiffer
(:meth:`PhysicsInputs.repair`); up to ``repair_rounds`` times, each round on what the last left
and the pairs found before, the self term ``repair_growth`` times stiffer each round. The anchor term couples frames; it takes the phase means from the
previous iterate, Jacobi-style, in both solvers. Weights are relative to ``EnergyConfig.w_kp``;
the defaults (floor, joint speed, the stance lock, feet apart and the self-penetration repair on;
stance height, flat feet, anchors and swing off) and what each measured are in docs/decisions.md
§Physical terms of the optimiser.
That is the ``method`` "penalty". The default, ``method`` "constraints", replaces all of that by
the plain solve and then the least change that meets the requirements as constraints
(:mod:`.constrained`; no goal edit, no repair round; docs/decisions.md §Physics as constraints).
Jacobians are analytic, the same form as the key points': a point ``p`` moving with node ``k``
moves by ``a_j x (p - p_j)`` for every joint ``j`` at or above ``k``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import torch

from mer_data.kinematics.collision import contact_points, pair_contacts

from . import goal_edits, repair, stance
from .faces import face_points
from .goal_edits import phase_mean
from .repair import SELF_POINTS

__all__ = ["PhysicsConfig", "PhysicsInputs", "Physics"]


@dataclass(frozen=True)
class PhysicsConfig:
    """Weights (relative to ``w_kp``) and thresholds [m], [1] of the physical terms."""

    w_floor: float = 1.0
    w_stance: float = 0.0
    w_flat: float = 0.0
    w_anchor: float = 0.0
    w_swing: float = 0.0
    swing_clearance: float = 0.01
    w_self: float = 3.0
    self_margin: float = 0.005
    max_contacts: int = 8  # self-penetration rows per frame
    self_repair_iters: int = 6  # > 0: the self term only in this many whole-window iterations after the solve, on the pairs it left interpenetrating
    repair_depth: float = 0.0025  # a pair interpenetrating deeper than this [m] in some frame triggers the repair
    repair_smooth: float = 8.0  # the temporal prior's weight in the repair, relative to the solve's
    repair_touch: float | None = 0.0  # frames where a body other than a foot is lower than this [m] get the repair too (None: not)
    repair_reach: int = 6  # the repair looks for a pair only within this many frames of where it was found (-1: every frame)
    repair_rounds: int = 3  # repairs in a row, each on the pairs still interpenetrating and those found before (self_repair_iters each)
    repair_growth: float = 2.0  # the self term's weight grows by this factor each round
    w_speed: float = 1.0
    speed_fraction: float = 0.95  # joint speed held under this share of the URDF velocity limit
    lock_blend: int = 4  # frames over which a stance foot's goals blend into and out of their anchor (-1: no lock)
    lock_weight: float = 1.0  # how far a stance foot's goals move to their anchor (1: all the way; 0: not at all)
    coarse: bool = True  # also in the optimiser's coarse (key-frame) stage, not only in the fine one
    feet_gap: float = 0.02  # the feet's goals kept this far apart beyond the target's foot width [m] (-1: off; PhysicsInputs.separate_feet)
    fine_iters: int = 8  # at least this many iterations of the fine (whole-window) stage (0: the optimiser's own)
    feasible: bool = True  # after the solve: joint speed clamped, base lifted off the floor (mer_models.retarget.feasible)
    method: str = "constraints"  # "constraints" (the default): the plain solve, then the least change that meets them (.constrained); "penalty": the terms above
    rho: float = 3.0  # constraints: the augmented Lagrangian's penalty weight, relative to w_kp
    al_rounds: int = 6  # constraints: most multiplier updates (each after al_iters whole-window iterations)
    al_extra: int = 3  # constraints: up to this many more rounds while a pair is 1 cm (constrained.DEEP_M) short of its margin and nearing it
    al_iters: int = 4  # constraints: whole-window iterations per round
    al_tries: int = 8  # constraints: at most this many linearisations per round (> al_iters: a refused step does not use up an iteration)
    al_smooth: float = 48.0  # constraints: the temporal prior's weight in the rounds, relative to the solve's (a smooth change)
    hover: float = 0.005  # constraints: a stance foot's lowest point at most this high [m] while the source's foot is down
    al_reach: int = 4  # constraints: frames this far from an active constraint move with it; the rest are held
    xy_weight: float = 1.0  # constraints: the stance anchor's weight, relative to rho (a penalty: its anchor moves each round)
    al_search: float = 0.03  # constraints: after the first round, pairs are looked for only among the entries this much [m] farther than active at its start
    al_focus: int = 2  # constraints: from this round on only frames near a constraint not yet met move (-1: never)
    al_gap: int = 8  # constraints: runs of such frames closer than this are solved together
    al_step: float = 1.0  # constraints: the multiplier update's step, times the violation (1: the augmented Lagrangian's)
    al_look: int = 2  # constraints: pairs looked for anew every this many rounds (and before the rounds stop; 0: only then)
    fixed_faces: bool = True  # constraints: a round's self rows along the separating faces chosen at its start (.faces)
    face_exact: float = 0.0  # constraints: entries overlapping deeper than this [m] at a round's start keep the exact separating-axis depth
    al_lift: bool = True  # constraints: the base first raised by how far a foot is in the floor (False: the rounds start from the plain solution)
    stance_xy: bool = True  # constraints: a stance foot's lowest body-fixed point kept from sliding while the source's foot is down (.stance)

    def __post_init__(self) -> None:
        if self.method not in ("constraints", "penalty"):
            raise ValueError(f"PhysicsConfig.method={self.method!r}: expected 'constraints' or 'penalty'")


@dataclass(frozen=True)
class PhysicsInputs:
    """What a solver needs for the physical terms of a batch (every sample the same robot).

    Attributes:
        model: the robot's :class:`~mer_data.robots.collision.CollisionModel`.
        contacts: (B, T, 2) bool, the source's feet down; None: no stance / swing terms.
        fps: the frames' rate [Hz]; cfg: the weights.
    """

    model: Any
    contacts: torch.Tensor | None
    fps: float
    cfg: PhysicsConfig = PhysicsConfig()
    ref_feet: tuple[tuple[int, ...], tuple[int, ...]] = ((), ())
    pairs: Any = None  # (K, 2) the shape pairs the self term looks at (None: those near at the first iterate)
    pair_mask: Any = None  # (B, K) or (B, T, K) bool: which of ``pairs`` each sample's (frame's) self term looks at (None: all)
    ref_knees: tuple[int, int] = (-1, -1)  # the reference's knee nodes (-1: none)
    free: Any = None  # (B, T) bool: the frames a repair may move (None: all; :meth:`repair`)
    found: Any = None  # (B, T, K) bool, the whole batch: the (frame, pair) entries repairs found so far (:meth:`repair`)
    al: Any = None  # the constraint method's round state (:mod:`.constrained`): shifts, fixed pair entries, anchors

    @classmethod
    def of_reference(cls, model: Any, contacts: torch.Tensor | None, fps: float, cfg: PhysicsConfig, ref: Any) -> "PhysicsInputs":
        """The inputs for a reference of skeleton ``ref`` (its sole and knee nodes looked up here)."""
        from mer_data.motion.contacts import sole_points

        sp = sole_points(ref)
        knees = (ref.keypoints.get("left_knee", -1), ref.keypoints.get("right_knee", -1))
        return cls(model, contacts, fps, cfg, (tuple(sp["left"]), tuple(sp["right"])), ref_knees=knees)

    def frames(self, idx: torch.Tensor, stride: int) -> "PhysicsInputs":
        """The same for every ``stride``-th frame ``idx`` (a coarse solve)."""
        c = None if self.contacts is None else self.contacts[:, idx]
        return dataclasses.replace(self, contacts=c, fps=self.fps / stride)

    @property
    def repairs(self) -> bool:
        """A repair runs after the solve (``cfg.self_repair_iters``): the self term there, not in it,
        and the frames where a body other than a foot is on the floor smoothed (``cfg.repair_touch``)."""
        return self.cfg.self_repair_iters > 0 and (self.cfg.w_self > 0 or self.cfg.repair_touch is not None)

    def main(self) -> "PhysicsInputs":
        """The terms of the main solve: without the self term where it runs as a repair."""
        return dataclasses.replace(self, cfg=dataclasses.replace(self.cfg, w_self=0.0)) if self.repairs else self

    def repair(self, pos: torch.Tensor, rot: torch.Tensor, first: bool = True, seen: torch.Tensor | None = None,
               moved: torch.Tensor | None = None) -> tuple[torch.Tensor, "PhysicsInputs"] | None:  # fmt: skip
        """The penalty method's repair terms (:func:`.repair.repair`)."""
        return repair.repair(self, pos, rot, first, seen, moved)

    def held_frames(self) -> torch.Tensor | None:
        """(B, T) bool: the frames a repair leaves where they are (:func:`.repair.held_frames`)."""
        return repair.held_frames(self)

    def lock_goals(self, goal: torch.Tensor) -> torch.Tensor:
        """The stance lock on position goals (B, T, Jr, 3) (:func:`.goal_edits.lock_goals`)."""
        return goal_edits.lock_goals(self, goal)

    def separate_feet(self, goal: torch.Tensor, heading: torch.Tensor) -> torch.Tensor:
        """The feet's goals kept apart (:func:`.goal_edits.separate_feet`)."""
        return goal_edits.separate_feet(self, goal, heading)

    def build(self, problem: Any, w_kp: float) -> "Physics":
        """The terms for a solver's problem (:class:`mer_models.solver.ik._Problem`)."""
        from .ik import ancestors

        g = problem.graph
        contacts = None if self.contacts is None else self.contacts.to(problem.dev)
        return Physics(self.cfg, w_kp, self.model, contacts, problem.fold, ancestors(g.parents), g.axes.to(problem.dtype), self.fps,
                       pairs=self.pairs, pair_mask=self.pair_mask, al=self.al)  # fmt: skip


SELF_REACH_M = 0.05  # pairs further apart than this at a solve's first iterate are not looked at in it
FLOOR_VERTICES = 4  # per shape, the lowest this many vertices are held above the floor


class Physics:
    """The physical terms of one batch (every sample the same robot).

    Args:
        cfg: weights; w_kp: the key-point weight they are relative to.
        model: the robot's :class:`~mer_data.robots.collision.CollisionModel`.
        contacts: (B, T, 2) bool, the source's feet down (None: no stance / swing terms).
        fold: (B, J, D) node → actuated column (mimic joints folded); fps: frame rate [Hz] (joint speed).
        anc: (B, J, J) ``[b, k, j]`` True iff j is a strict ancestor of k; axes (B, J, 3) node axes.
        pairs, pair_mask: (K, 2) the shape pairs the self term looks at (None: those within reach at the
            first iterate) and (B, K) which of them each sample looks at (None: all).
    """

    def __init__(self, cfg: PhysicsConfig, w_kp: float, model: Any, contacts: torch.Tensor | None, fold: torch.Tensor,
                 anc: torch.Tensor, axes: torch.Tensor, fps: float = 30.0, pairs: Any = None, pair_mask: Any = None, al: dict | None = None) -> None:  # fmt: skip
        self.cfg, self.model, self.fps, self.w_kp, self.al = cfg, model, fps, w_kp, al
        dev = fold.device
        # the self term's pairs (None: those near at the first iterate) and which of them each sample looks at
        self._near_pairs = None if pairs is None else torch.as_tensor(pairs, device=dev).reshape(-1, 2)
        self._pair_mask = None if pair_mask is None else torch.as_tensor(pair_mask, device=dev)
        self.feet_on = any(getattr(cfg, k) > 0 for k in ("w_stance", "w_flat", "w_anchor", "w_swing"))
        self.verts = torch.as_tensor(model.vertices, dtype=fold.dtype, device=fold.device)
        self.center = torch.as_tensor(model.center, dtype=fold.dtype, device=fold.device)
        self.radius = torch.as_tensor(model.radius, dtype=fold.dtype, device=fold.device)
        dtype, dev = fold.dtype, fold.device
        J = anc.shape[-1]
        self.moves = (anc | torch.eye(J, dtype=torch.bool, device=dev)).to(dtype)  # [b, k, j]: j moves a point on k
        self.fold, self.axes = fold, axes
        self.sw = {k: (getattr(cfg, k) * w_kp) ** 0.5 for k in ("w_floor", "w_stance", "w_flat", "w_anchor", "w_swing", "w_self")}
        self.contacts = contacts
        self.node = torch.as_tensor(model.node, device=dev)
        foot = torch.as_tensor(model.foot, device=dev)
        self.feet = [torch.nonzero(foot == s).flatten() for s in (1, 2)]
        foot_nodes = []
        for f in self.feet:  # the node carrying most of the foot (its rotation says if the foot is flat)
            nodes = self.node[f] if len(f) else torch.zeros(1, dtype=torch.long, device=dev)
            foot_nodes.append(int(torch.mode(nodes).values) if len(f) else -1)
        self.foot_node = foot_nodes

    # ---- state fixed for one iteration (Jacobi) ---------------------------------------------------------
    def freeze(self, pos: torch.Tensor, rot: torch.Tensor, qd: torch.Tensor) -> dict:
        """What the coupled terms hold fixed in an iteration: the stance anchors."""
        state: dict = {}
        if self.al is not None:  # the constraint method: entries and anchors fixed for a round
            state["self"] = self.al["entries"]
            state["anchor"] = self.al["anchor"]
            state["slip"] = self.al.get("slip")
            return state
        if self.cfg.w_self > 0:
            if self._near_pairs is None:  # the pairs within reach anywhere in the batch at the first iterate
                from mer_data.kinematics.collision import pair_depths

                with torch.no_grad():
                    d = pair_depths(self.model, pos, rot, margin=self.cfg.self_margin + SELF_REACH_M, which=SELF_POINTS)
                near = (d > -(self.cfg.self_margin + SELF_REACH_M)).flatten(0, -2).any(0)
                self._near_pairs = torch.as_tensor(self.model.pairs, device=pos.device)[near]
            state["pairs"] = self._near_pairs
            found = pair_contacts(self.model, pos, rot, margin=self.cfg.self_margin, top=self.cfg.max_contacts,
                                  pairs=self._near_pairs, which=SELF_POINTS, mask=self._pair_mask) if len(self._near_pairs) else None  # fmt: skip
            state["self"] = None if found is None else found[0]  # the (frame, pair) entries of this iteration
        if self.contacts is not None:
            state["anchor"] = [phase_mean(pos[:, :, n, :2], self.contacts[..., i]) if n >= 0 else None
                               for i, n in enumerate(self.foot_node)]  # fmt: skip
        return state

    # ---- rows ----------------------------------------------------------------------------------------------
    def _rows(self, pos: torch.Tensor, rot: torch.Tensor, state: dict):
        """Point rows (node, point, direction, weighted residual, Jacobian weight) and column rows (flat feet)."""
        B, T = pos.shape[:2]
        dev, dtype = pos.device, pos.dtype
        c = self.cfg
        S = self.node.shape[0]
        k = min(FLOOR_VERTICES, self.verts.shape[1])
        nodes, points, dirs, res, jws = [], [], [], [], []
        ez = torch.tensor([0.0, 0.0, 1.0], dtype=dtype, device=dev)
        # floor: the FLOOR_VERTICES lowest vertices of every shape whose bounding sphere reaches the floor (one
        # vertex alone would let a step tip the shape onto another corner)
        centre = torch.einsum("btsij,sj->btsi", rot[:, :, self.node], self.center) + pos[:, :, self.node]
        al = self.al or {}
        fs = al.get("floor")  # (B, T, S) the constraint method's shifts: held at or above them
        bottom = centre[..., 2] - self.radius  # (B, T, S) each bounding sphere's lowest point [m]
        bi, ti, si = (bottom < (0 if fs is None else fs)).nonzero(as_tuple=True)
        kz = bottom[..., None].expand(B, T, S, k).clone()  # a shape not looked at: its sphere's bottom, at or above the floor (its shift)
        kp = pos.new_zeros(B, T, S, k, 3)
        if len(bi):
            v = torch.einsum("eij,evj->evi", rot[bi, ti, self.node[si]], self.verts[si]) + pos[bi, ti, self.node[si]][:, None]
            z, vi = v[..., 2].topk(k, dim=-1, largest=False)
            kz[bi, ti, si] = z
            kp[bi, ti, si] = torch.gather(v, 1, vi[..., None].expand(-1, k, 3))
        nodes.append(self.node[:, None].expand(S, k).expand(B, T, S, k).reshape(B, T, S * k))
        points.append(kp.reshape(B, T, S * k, 3))
        dirs.append(ez.expand(B, T, S * k, 3))
        if fs is not None:
            kz = kz - fs[..., None]
        kz = kz.reshape(B, T, S * k)
        res.append(self.sw["w_floor"] * kz.clamp_max(0))
        jws.append(self.sw["w_floor"] * (kz < 0).to(dtype))
        col_nodes, col_dirs, col_res, col_w = [], [], [], []
        if self.contacts is not None and self.feet_on:
            fs = torch.cat(self.feet)  # the feet's shapes only
            verts = torch.einsum("btsij,svj->btsvi", rot[:, :, self.node[fs]], self.verts[fs]) + pos[:, :, self.node[fs], None]
            low_z, low_v = verts[..., 2].min(-1)  # (B, T, F)
            low_p = torch.gather(verts, 3, low_v[..., None, None].expand(*low_v.shape, 1, 3))[..., 0, :]  # (B, T, F, 3)
            at = 0
            for i, f in enumerate(self.feet):
                if not len(f):
                    continue
                down = self.contacts[..., i].to(dtype)  # (B, T)
                z, k = low_z[..., at : at + len(f)].min(-1)
                s = f[k]
                k = k + at
                at += len(f)
                nodes.append(self.node[s][..., None])
                points.append(torch.gather(low_p, 2, k[..., None, None].expand(B, T, 1, 3)))
                dirs.append(ez.expand(B, T, 1, 3))
                low = (z < c.swing_clearance).to(dtype) * (1 - down)
                if "stance_z" in al:  # the constraint: at most `hover` up (the floor holds it from below)
                    up = (z - c.hover + al["stance_z"][..., i]).clamp_min(0) * down
                    res.append((self.sw["w_stance"] * up)[..., None])
                    jws.append((self.sw["w_stance"] * (up > 0).to(dtype))[..., None])
                else:
                    r = self.sw["w_stance"] * z * down + self.sw["w_swing"] * (z - c.swing_clearance) * low
                    res.append(r[..., None])
                    jws.append((self.sw["w_stance"] * down + self.sw["w_swing"] * low)[..., None])
                n = self.foot_node[i]
                if state.get("anchor") is None or state["anchor"][i] is None:
                    continue
                for axis in range(2):  # stay put: the foot node's x, y at its stance phase's mean
                    e = torch.zeros(3, dtype=dtype, device=dev)
                    e[axis] = 1
                    nodes.append(torch.full((B, T, 1), n, device=dev))
                    points.append(pos[:, :, n : n + 1])
                    dirs.append(e.expand(B, T, 1, 3))
                    off = pos[:, :, n, axis] - state["anchor"][i][..., axis] + (al["stance_xy"][..., i, axis] if "stance_xy" in al else 0)
                    res.append((self.sw["w_anchor"] * off * down)[..., None])
                    jws.append((self.sw["w_anchor"] * down)[..., None])
                    col_nodes.append(n)
                    col_dirs.append(e)
                    col_res.append(self.sw["w_flat"] * rot[:, :, n, axis, 2] * down)  # the foot's z axis, tilted
                    col_w.append(self.sw["w_flat"] * down)
        # self-penetration: the deepest points
        entries = state.get("self")  # the contacts found at this iteration's start, measured at this pose
        slots = al["slots"] if "slots" in al else c.max_contacts
        ca = None
        if c.w_self > 0 and entries is not None:  # the constraint method's rounds: along faces fixed at the round's start
            ca = face_points(self.model, pos, rot, al["faces"], self.verts) if "faces" in al else contact_points(self.model, pos, rot, entries, slots, SELF_POINTS)
        if ca is not None:
            depth, pt, normal, na, nb = ca  # (B, T, K) ...
            if "self" in al:
                depth = depth + al["self"]
            active = (depth > -c.self_margin).to(dtype)
            depth = torch.where(active > 0, depth, torch.zeros_like(depth))  # padding is -inf
            nodes.append(torch.stack([na, nb], -1))  # rows with two bodies: handled via the 'other' node
            points.append(pt)
            dirs.append(-normal)
            res.append(self.sw["w_self"] * (depth + c.self_margin) * active)
            jws.append(self.sw["w_self"] * active)
        return nodes, points, dirs, res, jws, (col_nodes, col_dirs, col_res, col_w)

    def cost(self, pos: torch.Tensor, rot: torch.Tensor, qd: torch.Tensor, state: dict, rows: tuple | None = None) -> torch.Tensor:
        """(B, T) the terms' cost at a pose (the neighbours and anchors of ``state``; ``rows``: its rows, if made)."""
        _, _, _, res, _, (_, _, col_res, _) = self._rows(pos, rot, state) if rows is None else rows
        out = sum((r**2).sum(-1) for r in res)
        for r in col_res:
            out = out + r**2
        if state.get("slip") is not None:
            out = out + stance.slip_cost(self, pos, rot, state["slip"])
        return out

    def coupled_terms(self, pos: torch.Tensor, rot: torch.Tensor, state: dict):
        """The stance no-slip term's Gauss-Newton parts (:func:`.stance.slip_terms`), or None."""
        return None if state.get("slip") is None else stance.slip_terms(self, pos, rot, state["slip"])

    def linearise(self, pos: torch.Tensor, rot: torch.Tensor, qd: torch.Tensor, state: dict, with_cost: bool = False):
        """The terms' Gauss-Newton normal equations: ``J^T J`` (B, T, n, n) and ``J^T r`` (B, T, n); with
        ``with_cost`` also :meth:`cost` at this pose (B, T), from the same rows."""
        B, T, J = pos.shape[:3]
        rows_all = self._rows(pos, rot, state)
        nodes, points, dirs, res, jws, (col_nodes, col_dirs, col_res, col_w) = rows_all
        axes_w = (rot @ self.axes[:, None, :, :, None]).squeeze(-1)  # (B, T, J, 3)
        D = self.fold.shape[-1]
        n_cols = D + 6
        h = pos.new_zeros(B * T, n_cols, n_cols)
        g = pos.new_zeros(B * T, n_cols)
        ax_p = torch.linalg.cross(axes_w, pos, dim=-1).reshape(B * T, J, 3)  # a_j x p_j, once per frame
        ax = axes_w.reshape(B * T, J, 3)
        base = pos[:, :, 0].reshape(B * T, 3)
        for n, p, u, r, w in zip(nodes, points, dirs, res, jws):
            two = n.dim() == 4  # (B, T, K, 2): a pair of bodies (point on the first, normal of the second)
            act = (w != 0).nonzero(as_tuple=True)  # only the active rows are linearised
            if not len(act[0]):
                continue
            f = act[0] * T + act[1]  # frame of each row
            pe, ue, re, we = p[act], u[act], r[act], w[act]
            # u . (a_j x (p - p_j)) = a_j . (p x u) - u . (a_j x p_j)
            dq = torch.einsum("ejk,ek->ej", ax[f], torch.linalg.cross(pe, ue, dim=-1)) - torch.einsum("ejk,ek->ej", ax_p[f], ue)
            b = act[0]
            m = self.moves[b, (n[..., 0] if two else n)[act]]
            has = 0.0 if two else 1.0
            if two:
                m = m - self.moves[b, n[..., 1][act]]
            jq = (dq * m) @ self.fold[0] if self.fold.shape[0] == 1 else torch.einsum("ej,ejd->ed", dq * m, self.fold[b])  # one robot: no (E, J, D) gather
            jr = torch.linalg.cross(pe - base[f], ue, dim=-1) * has
            jrow = torch.cat([jq, ue * has, jr], -1) * we[:, None]  # (E, n), weighted like its residual
            h.index_add_(0, f, jrow[:, :, None] * jrow[:, None, :])
            g.index_add_(0, f, jrow * re[:, None])
        h, g = h.view(B, T, n_cols, n_cols), g.view(B, T, n_cols)
        rows, resid = [], []
        for n, e, r, w in zip(col_nodes, col_dirs, col_res, col_w):
            c = rot[:, :, n, :, 2]  # (B, T, 3) the foot's z axis
            dq = (torch.linalg.cross(axes_w, c[:, :, None].expand_as(axes_w)) * e).sum(-1)  # (B, T, J)
            jq = (dq * self.moves[:, n][:, None]) @ self.fold  # (B, T, D)
            jr = torch.linalg.cross(c, e.expand_as(c))
            jrow = torch.cat([jq, torch.zeros_like(c), jr], -1)[:, :, None] * w[..., None, None]
            rows.append(jrow)
            resid.append(r[..., None])
        if rows:
            jac = torch.cat(rows, 2)  # (B, T, R, n), rows weighted like their residuals
            rr = torch.cat(resid, 2)
            h = h + jac.transpose(-1, -2) @ jac
            g = g + (jac.transpose(-1, -2) @ rr[..., None])[..., 0]
        return (h, g, self.cost(pos, rot, qd, state, rows_all)) if with_cost else (h, g)

    # ---- joint speed: couples neighbouring frames exactly (coupled_lm_ik only) ----------------------------
    def _step_limit(self, cols: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
        """(B, 1, D) the largest angle change per frame of each column [rad] (inf: no limit)."""
        lim = torch.as_tensor(self.model.velocity_limit, dtype=like.dtype, device=like.device)
        return (torch.gather(lim[None].expand(cols.shape[0], -1), 1, cols) / self.fps * self.cfg.speed_fraction)[:, None]

    def speed_cost(self, qd: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
        """(B, T) ``w_speed * (|q_{t+1} - q_t| - limit)^2`` over the differences, each split between its frames."""
        out = torch.zeros(qd.shape[:2], dtype=qd.dtype, device=qd.device)
        if self.cfg.w_speed <= 0 or qd.shape[1] < 2:
            return out
        over = ((qd[:, 1:] - qd[:, :-1]).abs() - self._step_limit(cols, qd)).clamp_min(0)
        e = self.cfg.w_speed * self.w_kp * (over**2).sum(-1)
        out[:, 1:] += 0.5 * e
        out[:, :-1] += 0.5 * e
        return out

    def speed_terms(self, qd: torch.Tensor, cols: torch.Tensor):
        """The joint-speed term's Gauss-Newton parts: diagonal (B, T, D), coupling of frames t and
        t + 1 (B, T-1, D) and gradient ``J^T r`` (B, T, D); None when off."""
        if self.cfg.w_speed <= 0 or qd.shape[1] < 2:
            return None
        d = qd[:, 1:] - qd[:, :-1]
        over = d.abs() - self._step_limit(cols, qd)
        act = (over > 0).to(qd.dtype)
        w = self.cfg.w_speed * self.w_kp * act
        diag = torch.zeros_like(qd)
        diag[:, 1:] += w
        diag[:, :-1] += w
        r = w * torch.sign(d) * over.clamp_min(0)  # d cost / d q_{t+1}, halved
        grad = torch.zeros_like(qd)
        grad[:, 1:] += r
        grad[:, :-1] -= r
        return diag, -w, grad
