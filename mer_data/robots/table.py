"""The node table of ``mer robots show`` (also printed by ``mer robots register --dry-run``)."""

from __future__ import annotations

from mer_data.skeleton import Skeleton

__all__ = ["skeleton_table"]


def skeleton_table(skel: Skeleton, *, description: str, urdf: str, source: str) -> str:
    """One line per node: kind, parent, axis, limits, zero-pose position and the key point it carries."""
    s = skel
    lines = [
        f"{s.name}: {description}",
        f"  urdf {urdf}  ({source})",
        f"  {s.num_nodes} nodes, {s.num_dof} actuated joints" + (f", locked {len(s.locked)}" if s.locked else ""),
    ]
    inv = {v: k for k, v in s.keypoints.items() if v >= 0}
    rest = s.rest_positions
    lines.append(
        f"  {'#':>3s} {'node':28s} {'kind':8s} {'parent':>6s} {'axis':>20s} {'limits [rad]':>17s} "
        f"{'zero-pose pos [m]':>24s} key"
    )
    for j in range(s.num_nodes):
        ax = "" if s.node_kinds[j] != "revolute" else "({:+.2f} {:+.2f} {:+.2f})".format(*s.axes[j])
        lim = "" if s.node_kinds[j] != "revolute" else f"[{s.lower[j]:+.2f}, {s.upper[j]:+.2f}]"
        pos = "({:+.3f} {:+.3f} {:+.3f})".format(*rest[j])
        lines.append(
            f"  {j:3d} {s.node_names[j]:28s} {s.node_kinds[j]:8s} {s.parents[j]:6d} {ax:>20s} {lim:>17s} "
            f"{pos:>24s} {inv.get(j, '')}"
        )
    missing = [k for k, v in s.keypoints.items() if v < 0]
    if missing:
        lines.append(f"  absent key points: {', '.join(missing)}")
    return "\n".join(lines)
