"""`mer train`, `mer retarget`, `mer evaluate` end to end through main(argv), and their refusals."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from model_helpers import micro_checkpoint, synthetic_csv  # noqa: F401 (fixture)

from mer_data.robots.registry import get_skeleton
from mer_models.cli import main


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_train_command_writes_a_checkpoint(tmp_path, capsys):
    code, out, err = run(capsys, "train", "--config", "tiny", "--synthetic", "8", "--steps", "2", "--batch-size", "4", "--log-every", "1", "--out", tmp_path / "c")
    assert code == 0, err
    assert "checkpoint" in out and "step      2" in err
    meta = json.loads((tmp_path / "c" / "config.json").read_text())
    assert meta["run"]["name"] == "tiny" and meta["data"]["synthetic"] == 8


def test_train_ref_group_needs_shards(tmp_path, capsys):
    code, _, err = run(capsys, "train", "--config", "tiny", "--synthetic", "8", "--steps", "1", "--batch-size", "4",
                       "--ref-group", "2", "--out", tmp_path / "c")  # fmt: skip
    assert code == 1 and err.startswith("error:"), err
    assert "train.ref_group" in err and "ShardDataset" in err, err
    assert not (tmp_path / "c").exists()


def test_retarget_writes_every_output_within_limits(tmp_path, capsys, micro_checkpoint):  # noqa: F811
    src = synthetic_csv(tmp_path / "walk.csv")
    out = tmp_path / "out"
    code, o, err = run(capsys, "retarget", src, "--source", "g1", "--target", "h1", "--model", micro_checkpoint,
                       "-o", out / "h1.csv", "--npz", out / "h1.npz", "--npz-for", "mjlab", "--mcap", out / "h1.mcap", "--plot", out / "h1.png", "--steps", "3")  # fmt: skip
    assert code == 0, err
    for ext in ("csv", "npz", "mcap", "png"):
        assert (out / f"h1.{ext}").stat().st_size > 0
    a = np.loadtxt(out / "h1.csv", delimiter=",")
    h1 = get_skeleton("h1")
    assert a.shape == (90, 7 + 19)
    from mer_models.export.writers import csv_columns

    idx = [h1.node_index(n) for n in csv_columns(h1)]
    assert (a[:, 7:] >= h1.lower[idx] - 1e-5).all() and (a[:, 7:] <= h1.upper[idx] + 1e-5).all()


def test_retarget_with_the_optimisation_baseline_needs_no_model(tmp_path, capsys):
    src = synthetic_csv(tmp_path / "walk.csv", frames=40)
    code, _, err = run(capsys, "retarget", src, "--source", "g1", "--target", "tron1", "--method", "optimize", "-o", tmp_path / "t.csv")
    assert code == 0, err
    assert np.loadtxt(tmp_path / "t.csv", delimiter=",").shape == (40, 7 + 8)


@pytest.mark.parametrize(
    "case, expect",
    [
        ("unknown_robot", "unknown robot 'r2d2'"),
        ("wrong_columns", "h1.csv"),
        ("nan", "walk.csv:5"),
        ("unseen", "mer finetune"),
        ("config", "model.relative_bias"),
    ],
)
def test_bad_input_is_a_clear_error(tmp_path, capsys, micro_checkpoint, case, expect):  # noqa: F811
    src = synthetic_csv(tmp_path / "walk.csv", frames=30)
    args = ["retarget", src, "--source", "g1", "--target", "h1", "--model", micro_checkpoint, "-o", tmp_path / "o.csv"]
    if case == "unknown_robot":
        args[5] = "r2d2"
    elif case == "wrong_columns":
        args[1] = synthetic_csv(tmp_path / "h1.csv", robot="h1", frames=30)  # an H1 file given as G1
    elif case == "nan":
        lines = src.read_text().splitlines()
        cells = lines[4].split(",")
        cells[9] = "nan"
        lines[4] = ",".join(cells)
        src.write_text("\n".join(lines) + "\n")
    elif case == "unseen":
        args[5] = "valkyrie"
    elif case == "config":
        ck = tmp_path / "ck"
        shutil.copytree(micro_checkpoint, ck)
        meta = json.loads((ck / "config.json").read_text())
        meta["run"]["model"]["relative_bias"] = True
        (ck / "config.json").write_text(json.dumps(meta))
        args[7] = ck
    code, _, err = run(capsys, *args)
    assert code == 1 and err.startswith("error:"), err
    assert expect in err, err
    assert not (tmp_path / "o.csv").exists()


def test_evaluate_prints_the_papers_table(tmp_path, capsys, micro_checkpoint):  # noqa: F811
    data = tmp_path / "data"
    clips = ["dance1_subject1", "fallAndGetUp1_subject1", "fight1_subject2", "walk1_subject1"]
    for k, clip in enumerate(clips):
        synthetic_csv(data / "g1" / f"{clip}.csv", "g1", frames=120, seed=k)
        synthetic_csv(data / "h1" / f"{clip}.csv", "h1", frames=120, seed=10 + k)
    code, out, err = run(capsys, "evaluate", "--model", micro_checkpoint, "--input", data, "--source", "g1",
                         "--targets", "g1", "h1", "tron1", "--max-windows", "2", "--steps", "2", "--save", tmp_path / "r.json",
                         "--opt-iters", "10", "--opt-gn-iters", "10", "--no-physics")  # fmt: skip
    # the table and its rows; the physical terms' path of evaluate: the run below, test_artifacts and test_real_data
    assert code == 0, err
    assert "in-domain" in out and "out-of-domain" in out and "E_g-mpbpe [m]" in out
    report = json.loads((tmp_path / "r.json").read_text())
    rows = {(r["robot"], r["domain"], r["method"]) for r in report["rows"]}
    assert len(rows) == 3 * 2 * 2
    g1_opt = next(r for r in report["rows"] if r["robot"] == "g1" and r["method"] == "optimize" and r["domain"] == "in-domain")
    assert g1_opt["metrics"]["g_mpbpe"]["mean"] < 0.02  # the baseline tracks a reachable reference
    assert g1_opt["metrics"]["gt_mpbpe"]["n"] == 2  # G1 data is the ground truth of G1 targets
    assert all(r["metrics"]["limit_violation"]["mean"] == 0 for r in report["rows"])
    code, out, _ = run(capsys, "evaluate", "--input", data, "--targets", "tron1", "--max-windows", "1", "--json", "--opt-iters", "2", "--opt-gn-iters", "2")
    assert code == 0 and json.loads(out)["rows"][0]["method"] == "optimize"


def test_a_robot_without_lafan1_data_is_a_source_in_mers_own_layout(tmp_path, capsys):
    """What `mer retarget -o` writes for Atlas (no LAFAN1 layout) is read back as an Atlas source."""
    src = synthetic_csv(tmp_path / "walk.csv", frames=40)
    code, _, err = run(capsys, "retarget", src, "--source", "g1", "--target", "atlas", "--method", "optimize", "-o", tmp_path / "atlas.csv")
    assert code == 0, err
    code, _, err = run(capsys, "retarget", tmp_path / "atlas.csv", "--source", "atlas", "--target", "h1", "--method", "optimize",
                       "-o", tmp_path / "h1.csv")  # fmt: skip
    assert code == 0, err
    assert np.loadtxt(tmp_path / "h1.csv", delimiter=",").shape == (40, 7 + 19)


def test_balance_runs_in_the_optimiser_and_is_refused_without_one(tmp_path, capsys):
    """``--balance`` (docs/model.md §Balance): the optimiser writes the motion, in a single file's run and in a
    dataset run (whose metrics then read no more infeasible frames than without it); a run with no optimiser
    stage (the model alone) is refused before any work."""
    src = synthetic_csv(tmp_path / "in" / "g1" / "walk.csv", frames=40)
    code, _, err = run(capsys, "retarget", src, "--source", "g1", "--target", "g1", "--method", "optimize", "--no-physics", "--balance",
                       "-o", tmp_path / "b.csv")  # fmt: skip
    assert code == 0, err
    assert np.loadtxt(tmp_path / "b.csv", delimiter=",").shape[0] == 40
    code, _, err = run(capsys, "retarget", src, "--source", "g1", "--target", "g1", "--method", "diffusion", "--balance", "-o", tmp_path / "d.csv")
    assert code == 1 and "--balance works in the optimiser" in err and "--method optimize" in err, err
    assert not (tmp_path / "d.csv").exists()
    rows = {}
    for name, extra in (("plain", []), ("balance", ["--balance"])):
        code, _, err = run(capsys, "retarget", "--input", tmp_path / "in", "--source", "g1", "--targets", "g1", "--out", tmp_path / name,
                           "--no-physics", "--workers", "1", *extra)  # fmt: skip
        assert code == 0, err
        rows[name] = json.loads((tmp_path / name / "g1" / "walk.metrics.json").read_text())
    assert rows["plain"]["balance_infeasible"] > 0
    assert rows["balance"]["balance_infeasible"] < rows["plain"]["balance_infeasible"], rows
    plain = np.loadtxt(tmp_path / "plain" / "g1" / "walk.csv", delimiter=",")
    assert np.abs(np.loadtxt(tmp_path / "balance" / "g1" / "walk.csv", delimiter=",") - plain).max() > 1e-3


def test_evaluate_balance_runs_the_term_in_the_optimiser_and_is_refused_without_one(tmp_path, capsys):
    """``mer evaluate --balance``: the optimiser's windows with the balance term (the report says so, and its
    windows read fewer infeasible frames than without it); refused where no method runs the optimiser."""
    data = tmp_path / "data"
    synthetic_csv(data / "g1" / "walk1_subject1.csv", "g1", frames=120, seed=0)
    reports = {}
    for name, extra in (("plain", []), ("balance", ["--balance"])):
        code, out, err = run(capsys, "evaluate", "--input", data, "--targets", "g1", "--methods", "optimize", "--split", "all",
                             "--max-windows", "1", "--no-physics", "--json", *extra)  # fmt: skip
        assert code == 0, err
        reports[name] = json.loads(out)
    assert reports["plain"]["options"]["balance"] is None and reports["balance"]["options"]["balance"]["method"] == "path"
    inf = {k: r["rows"][0]["metrics"]["balance_infeasible"]["mean"] for k, r in reports.items()}
    assert inf["balance"] < inf["plain"], inf
    code, _, err = run(capsys, "evaluate", "--input", data, "--targets", "g1", "--methods", "model", "--balance")
    assert code == 1 and "--balance works in the optimiser" in err and "--methods optimize" in err, err
