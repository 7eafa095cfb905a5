"""Benchmark: mer's batched FK against pytorch_kinematics on the same batch.

G1, 245,760 random configurations (within limits) and random base poses, float32, CPU threads as
the machine has. Prints forward and forward+backward times (median of --repeat runs) for both, and
the ratios pk / mer (> 1 means mer is faster). The two agree on every position (checked here too).

    python tools/bench_fk.py [--robot g1] [--batch 245760] [--chunk 0] [--repeat 5]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors  # noqa: E402
from mer_data.kinematics.rotations import quat_to_matrix  # noqa: E402
from mer_data.robots.registry import load_robot  # noqa: E402


def pk_chain(urdf_path: Path):
    import pytorch_kinematics as pk

    text = re.sub(r"<material>\s*(<color[^>]*/>)?\s*</material>", "", urdf_path.read_text())
    text = re.sub(r"<\?xml[^>]*\?>", "", text)
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        return pk.build_chain_from_urdf(text).to(dtype=torch.float32)


def timed(fn, repeat: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def chunks(n: int, size: int):
    size = size or n
    return [(i, min(n, i + size)) for i in range(0, n, size)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="g1")
    ap.add_argument("--batch", type=int, default=245_760)
    ap.add_argument("--chunk", type=int, default=0, help="evaluate in chunks of this size (0: one batch)")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()

    robot = load_robot(args.robot)
    skel = robot.skeleton
    st = skeleton_tensors(skel, torch.float32)
    chain = pk_chain(robot.urdf_path)
    gen = torch.Generator().manual_seed(0)
    n = args.batch
    q = st.lower + (st.upper - st.lower) * torch.rand(n, skel.num_nodes, generator=gen)
    q = q * torch.tensor(skel.revolute_mask, dtype=torch.float32)
    base_pos = torch.randn(n, 3, generator=gen)
    base_rot = quat_to_matrix(torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=-1))
    names = chain.get_joint_parameter_names()
    node_of = {nm: j for j, nm in enumerate(skel.urdf_joint_names) if nm is not None}
    th = torch.zeros(n, len(names))
    for i, nm in enumerate(names):
        if nm in node_of:
            th[:, i] = q[:, node_of[nm]]
        elif nm in skel.locked:
            th[:, i] = skel.locked[nm]

    def mer_fwd(grad: bool):
        def run():
            for a, b in chunks(n, args.chunk):
                qq = q[a:b].clone().requires_grad_(grad)
                with torch.set_grad_enabled(grad):
                    pos, rot = fk_skeleton(st, qq, base_pos[a:b], base_rot=base_rot[a:b])
                    if grad:
                        (pos.sum() + rot.sum()).backward()

        return run

    def pk_fwd(grad: bool):
        def run():
            for a, b in chunks(n, args.chunk):
                tt = th[a:b].clone().requires_grad_(grad)
                with torch.set_grad_enabled(grad):
                    m = chain.forward_kinematics_tensor(tt)  # (frames, B, 4, 4), base frame
                    pos = base_rot[a:b] @ m[..., :3, 3:] + base_pos[a:b, :, None]
                    rot = base_rot[a:b] @ m[..., :3, :3]
                    if grad:
                        (pos.sum() + rot.sum()).backward()

        return run

    # correctness on a slice before timing
    with torch.no_grad():
        pos, _ = fk_skeleton(st, q[:512], base_pos[:512], base_rot=base_rot[:512])
        m = chain.forward_kinematics_tensor(th[:512])
        idx = chain.get_frame_indices(*[skel.link_names[j] for j in range(skel.num_nodes) if skel.node_kinds[j] != "site"])
        ref = (base_rot[:512] @ m[idx][..., :3, 3:]).squeeze(-1) + base_pos[:512]
        mine = pos[:, [j for j in range(skel.num_nodes) if skel.node_kinds[j] != "site"]].transpose(0, 1)
        err = (ref - mine).abs().max().item()

    print(f"robot {skel.name}: {skel.num_nodes} nodes ({skel.num_dof} joints) | pytorch_kinematics: "
          f"{len(chain.get_frame_names(exclude_fixed=False))} frames | batch {n:,} | chunk {args.chunk or n:,} | "
          f"float32 | threads {torch.get_num_threads()} | max |Δpos| {err:.2e} m")  # fmt: skip
    rows = []
    for label, grad in (("forward", False), ("forward+backward", True)):
        t_mer = timed(mer_fwd(grad), args.repeat)
        t_pk = timed(pk_fwd(grad), args.repeat)
        rows.append((label, t_mer, t_pk))
        print(f"{label:18s} mer {t_mer * 1e3:9.1f} ms   pytorch_kinematics {t_pk * 1e3:9.1f} ms   "
              f"ratio pk/mer {t_pk / t_mer:5.2f}x   ({n / t_mer / 1e6:.2f} M configs/s)")  # fmt: skip


if __name__ == "__main__":
    main()
