"""``mer shards solve``: teacher targets in the shards, read back by ``ShardDataset`` and training."""

from __future__ import annotations

import json
import shutil

import h5py
import numpy as np
import pytest
import torch
from model_helpers import MICRO, micro_run

from mer_data.base.errors import MerError, ShardFormatError
from mer_data.motion.samples import collate
from mer_data.shards import ShardDataset
from mer_data.shards.teacher import teacher_path
from mer_models.cli import main
from mer_models.config import EnergyConfig
from mer_models.diffusion.model import RetargetModel
from mer_models.retarget.inference import optimize_batch
from mer_models.training.teacher import SolverConfig, solve_shards
from mer_models.training.train import clean_samples

GN = 4  # iterations: enough to test the plumbing quickly


def _build(out):
    assert main(["shards", "build", "--synthetic", "1", "--synthetic-seconds", "4", "--robots", "g1", "--targets", "g1", "h1",
                 "--augment", "1", "--workers", "1", "--quiet", "--out", str(out)]) == 0  # fmt: skip
    return out


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    out = _build(tmp_path_factory.mktemp("teacher"))
    assert main(["shards", "solve", str(out), "--gn-iters", str(GN), "--batch", "3", "--quiet", "--json"]) == 0
    return out


def test_solve_writes_one_complete_teacher_file_per_shard(solved):
    shard = next(solved.glob("*.h5"))
    path = teacher_path(shard)
    assert path == solved / "teacher" / shard.name and path.is_file()
    assert not list(path.parent.glob("*.partial"))
    with h5py.File(path) as f:
        assert f["solved"][()].all() and np.isfinite(f["energy"][()]).all()
        assert json.loads(f.attrs["solver"])["gn_iters"] == GN and f.attrs["frames"] > 0
    ds = ShardDataset(solved)  # the teacher/ subfolder is not mistaken for a shard
    assert len(ds.files) == 1 and ds.has_teacher


def test_teacher_sample_is_the_optimisers_solution(solved):
    """What training reads equals solving the same samples again, one by one (FK at load, mimic
    applied): with the physical terms where the target is the registered robot as it is, without
    them for an augmented variant (it has no collision geometry of its own)."""
    from mer_data.robots.collision import collision_model
    from mer_data.robots.registry import load_robot
    from mer_models.batch import batch_features, graph_from_batch
    from mer_models.solver.physics import PhysicsConfig

    ds = ShardDataset(solved)
    idx = [i for i in range(len(ds)) if ds[i].provenance["target"] == "h1"][:3]  # variant 0 and augmented
    samples = [ds[i] for i in idx]
    assert all(s.teacher is not None for s in samples) and any(s.provenance["augmented"] for s in samples)
    assert not all(s.provenance["augmented"] for s in samples)
    h1 = load_robot("h1")
    for s in samples:
        batch = collate([s])
        kw = {} if s.provenance["augmented"] else {
            "physics": PhysicsConfig(), "geometry": collision_model(h1), "ref_skeleton": s.reference_skeleton, "fps": 30.0,
            "target_skeleton": s.target_skeleton}  # fmt: skip
        again = optimize_batch(EnergyConfig(), batch, gn_iters=GN, **kw)
        feats = batch_features(graph_from_batch(batch, "tgt", "cpu"), again["q"], again["base_pos"], again["base_rot"])
        torch.testing.assert_close(batch["teacher"], feats, atol=2e-4, rtol=0)
        np.testing.assert_allclose(s.provenance["teacher_energy"], again["energy"].numpy()[0], rtol=1e-3)


def test_training_reads_x_from_the_teacher(solved):
    ds = ShardDataset(solved)
    batch = collate([ds[i] for i in range(4)])
    m = RetargetModel(MICRO)
    run = micro_run()
    cond = m.conditions(batch)
    x = clean_samples(m, batch, cond, run)
    e = m.energy(x, cond, run.energy)
    assert float(e["cst"].max()) < 1e-8  # FK-consistent features
    # the energy of x is the teacher's own residual (a rigid change of frame moves goals and x alike)
    teacher_energy = [p["teacher_energy"] for p in batch["provenance"]]
    np.testing.assert_allclose(e["total"].numpy(), teacher_energy, rtol=2e-3)
    ds_none = ShardDataset(solved, teacher=None)
    b2 = collate([ds_none[i] for i in range(4)])
    assert not b2["has_teacher"].any()


def test_a_killed_solve_resumes_and_gives_the_same_file(solved, tmp_path, monkeypatch):
    out = tmp_path / "s"
    shutil.copytree(solved, out, ignore=shutil.ignore_patterns("teacher"))
    import mer_models.training.teacher as teacher

    calls = {"n": 0}
    real = teacher._solve_samples  # once per batch

    def dies_on_second(*a, **k):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(teacher, "_solve_samples", dies_on_second)
    with pytest.raises(KeyboardInterrupt):
        solve_shards(out, solver=SolverConfig(gn_iters=GN, batch=3))
    shard = next(out.glob("*.h5"))
    final = teacher_path(shard)
    partial = final.with_name(final.name + ".partial")
    assert not final.exists() and partial.exists()  # nothing under the final name until complete
    with h5py.File(partial) as f:
        assert 0 < f["solved"][()].sum() < f["solved"].size
    monkeypatch.setattr(teacher, "_solve_samples", real)
    rec = solve_shards(out, solver=SolverConfig(gn_iters=GN, batch=3))
    assert rec[0]["status"] == "solved" and final.exists() and not partial.exists()
    with h5py.File(final) as a, h5py.File(teacher_path(next(solved.glob("*.h5")))) as b:
        for k in ("q", "base_pos", "base_rotvec", "energy"):
            np.testing.assert_allclose(a[k][()], b[k][()], atol=1e-5, err_msg=k)
    assert solve_shards(out, solver=SolverConfig(gn_iters=GN, batch=3))[0]["status"] == "up to date"


def test_another_configuration_is_refused_without_force(solved, tmp_path):
    out = tmp_path / "s"
    shutil.copytree(solved, out)
    with pytest.raises(MerError, match="--force"):
        solve_shards(out, solver=SolverConfig(gn_iters=GN + 1))
    assert main(["shards", "solve", str(out), "--gn-iters", str(GN + 1)]) == 1


def test_a_teacher_of_another_build_is_refused_on_load(solved, tmp_path):
    out = tmp_path / "s"
    shutil.copytree(solved, out)
    path = teacher_path(next(out.glob("*.h5")))
    with h5py.File(path, "r+") as f:
        f.attrs["shard_build_id"] = "other"
    with pytest.raises(ShardFormatError, match="another build"):
        ShardDataset(out)
    with pytest.raises(ShardFormatError, match="no teacher file"):
        ShardDataset(out, teacher=tmp_path / "nowhere")


def test_sharded_solve_covers_each_file_once(tmp_path):
    out = tmp_path / "two"
    assert main(["shards", "build", "--synthetic", "1", "--synthetic-seconds", "2.5", "--robots", "g1", "h1", "--targets", "g1",
                 "--augment", "0", "--workers", "1", "--quiet", "--out", str(out)]) == 0  # fmt: skip
    a = solve_shards(out, solver=SolverConfig(gn_iters=2), shard_index=0, num_shards=2)
    b = solve_shards(out, solver=SolverConfig(gn_iters=2), shard_index=1, num_shards=2)
    assert len(a) == len(b) == 1 and a[0]["shard"] != b[0]["shard"]
    assert ShardDataset(out).has_teacher


def test_teacher_samples_load_in_dataloader_workers(solved):
    """Worker processes open their own teacher handles (pickled without the open file)."""
    ds = ShardDataset(solved)
    loader = torch.utils.data.DataLoader(ds, batch_size=2, num_workers=2, collate_fn=collate)
    batch = next(iter(loader))
    assert batch["has_teacher"].all()
    torch.testing.assert_close(batch["teacher"], collate([ds[0], ds[1]])["teacher"])


def test_hub_shards_need_an_out_folder():
    with pytest.raises(MerError, match="--out"):
        solve_shards("hf://datasets/someone/shards")


def test_threads_option_sets_the_jobs_threads_and_refuses_zero(solved, tmp_path, capsys):
    """``--threads N``: the solve runs on N threads (parallel jobs on one machine share its cores)."""
    before = torch.get_num_threads()
    out = tmp_path / "s"
    shutil.copytree(solved, out)
    try:
        n = 2 if before == 1 else 1  # a count other than the one it ran on (one under pytest -n)
        assert main(["shards", "solve", str(out), "--gn-iters", str(GN), "--batch", "3", "--quiet", "--threads", str(n)]) == 0
        assert torch.get_num_threads() == n
        assert "up to date" in capsys.readouterr().out
        assert main(["shards", "solve", str(out), "--threads", "0"]) == 1
        assert "--threads must be >= 1" in capsys.readouterr().err
    finally:
        torch.set_num_threads(before)


def test_the_teacher_solves_with_the_schedule_it_records(solved, tmp_path):
    """``SolverConfig.optimizer_version`` is recorded in the teacher file and is what runs: version 1
    solves with the Jacobi fine stage (the teachers written before version 2), not the default
    whole-window one; other versions are refused."""
    from mer_models.solver.optimize import OPTIMIZER_VERSION

    assert SolverConfig().optimizer_version == OPTIMIZER_VERSION == 2
    with pytest.raises(MerError, match="optimizer_version 3"):
        SolverConfig(optimizer_version=3)
    out = tmp_path / "v1"
    shutil.copytree(solved, out)
    assert main(["shards", "solve", str(out), "--gn-iters", str(GN), "--optimizer-version", "1", "--batch", "3", "--quiet",
                 "--no-physics"]) == 1  # refused: v2 there (and with the physical terms)
    assert main(["shards", "solve", str(out), "--gn-iters", str(GN), "--optimizer-version", "1", "--batch", "3", "--quiet", "--force",
                 "--no-physics"]) == 0  # the schedule alone, without the physical terms
    ds = ShardDataset(out)
    assert ds.teachers[0].solver["optimizer_version"] == 1 and ds.teachers[0].solver["physics"] is None
    idx = [i for i in range(len(ds)) if ds[i].provenance["target"] == "h1"][:3]
    batch = collate([ds[i] for i in idx])
    from mer_models.batch import batch_features, graph_from_batch

    g = graph_from_batch(batch, "tgt", "cpu")

    def features(fine: str) -> torch.Tensor:
        m = optimize_batch(EnergyConfig(), batch, gn_iters=GN, fine=fine)
        return batch_features(g, m["q"], m["base_pos"], m["base_rot"])

    torch.testing.assert_close(batch["teacher"], features("jacobi"), atol=2e-4, rtol=0)
    assert (batch["teacher"] - features("coupled")).abs().max() > 1e-3  # the two schedules differ


def test_a_human_reference_is_solved_with_the_human_feet(tmp_path):
    """A shard of human motion (BVH) is solved as ``mer retarget`` solves a human source: the
    constraint method that plants the stance feet (``human_physics``), not the robot's penalty terms."""
    from bvh_factory import BANDAI_NAMES, human_definition, smooth_motion, write_bvh

    from mer_data.robots.collision import collision_model
    from mer_data.robots.registry import load_robot
    from mer_data.shards import BuildConfig, build_shards
    from mer_models.batch import batch_features, graph_from_batch
    from mer_models.retarget.clip import human_physics
    from mer_models.solver.physics import PhysicsConfig

    d = tmp_path / "in" / "bvh"
    d.mkdir(parents=True)
    rng = np.random.default_rng(3)
    (d / "walk.bvh").write_text(write_bvh(smooth_motion(human_definition(rng, 64, BANDAI_NAMES, angle=10.0), rng), six=True))
    out = tmp_path / "out"
    build_shards(BuildConfig(input=str(tmp_path / "in"), robots=("bvh",), targets=("g1",), split="all", augment=0), out)
    solve_shards(out, solver=SolverConfig(gn_iters=2))
    sample = ShardDataset(out)[0]
    assert sample.reference_skeleton.name == "bvh" and sample.teacher is not None
    batch = collate([sample])
    kw = {"geometry": collision_model(load_robot("g1")), "ref_skeleton": sample.reference_skeleton, "fps": 30.0,
          "target_skeleton": sample.target_skeleton}  # fmt: skip

    def feats(physics):
        m = optimize_batch(EnergyConfig(), batch, gn_iters=2, physics=physics, **kw)
        return batch_features(graph_from_batch(batch, "tgt", "cpu"), m["q"], m["base_pos"], m["base_rot"])

    torch.testing.assert_close(batch["teacher"], feats(human_physics()), atol=2e-4, rtol=0)
    assert float((batch["teacher"] - feats(PhysicsConfig(method="penalty"))).abs().max()) > 1e-3  # not the penalty terms


def test_physics_method_penalty_is_what_the_teacher_solves_and_records(solved, tmp_path, capsys):
    """``--physics-method penalty``: the robot-source samples are solved by the penalty method (the
    default is the constraint method, issue 50), recorded in the teacher file; over a teacher of the
    default it needs --force; with --no-physics it is refused."""
    from mer_data.robots.collision import collision_model
    from mer_data.robots.registry import load_robot
    from mer_models.batch import batch_features, graph_from_batch
    from mer_models.solver.physics import PhysicsConfig

    out = tmp_path / "c"
    shutil.copytree(solved, out)
    assert main(["shards", "solve", str(out), "--gn-iters", str(GN), "--batch", "3", "--quiet", "--physics-method", "penalty"]) == 1
    assert "--force" in capsys.readouterr().err  # a teacher of the constraint method is there
    assert main(["shards", "solve", str(out), "--gn-iters", str(GN), "--batch", "3", "--quiet", "--physics-method", "penalty",
                 "--force"]) == 0  # fmt: skip
    ds = ShardDataset(out)
    assert ds.teachers[0].solver["physics"]["method"] == "penalty"
    s = next(ds[i] for i in range(len(ds)) if ds[i].provenance["target"] == "h1" and not ds[i].provenance["augmented"])
    batch = collate([s])
    kw = {"geometry": collision_model(load_robot("h1")), "ref_skeleton": s.reference_skeleton, "fps": 30.0, "target_skeleton": s.target_skeleton}

    def feats(physics):
        m = optimize_batch(EnergyConfig(), batch, gn_iters=GN, physics=physics, **kw)
        return batch_features(graph_from_batch(batch, "tgt", "cpu"), m["q"], m["base_pos"], m["base_rot"])

    torch.testing.assert_close(batch["teacher"], feats(PhysicsConfig(method="penalty")), atol=2e-4, rtol=0)
    assert main(["shards", "solve", str(out), "--no-physics", "--physics-method", "penalty"]) == 1
    assert "--no-physics" in capsys.readouterr().err
