"""``--refine K``: the model's output as the optimiser's warm start (mer evaluate and mer retarget)."""

from __future__ import annotations

import json

import numpy as np

from mer_models.cli import main

from model_helpers import micro_checkpoint, synthetic_csv  # noqa: F401 (fixture)


def test_evaluate_refine_sits_between_the_model_and_the_optimiser(tmp_path, capsys, micro_checkpoint):  # noqa: F811
    data = tmp_path / "data"
    for k in range(2):
        synthetic_csv(data / "g1" / f"clip{k}.csv", "g1", frames=120, seed=k)
    code = main(["evaluate", "--model", str(micro_checkpoint), "--input", str(data), "--source", "g1", "--targets", "h1",
                 "--split", "all", "--max-windows", "2", "--steps", "2", "--methods", "model", "refine", "optimize",
                 "--refine", "8", "--save", str(tmp_path / "r.json")])  # fmt: skip
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "fr/s" in out.out and "refine" in out.out
    rows = {r["method"]: r for r in json.loads((tmp_path / "r.json").read_text())["rows"]}
    g = {m: rows[m]["metrics"]["g_mpbpe"]["mean"] for m in rows}
    # a 3-step micro model is metres off; 8 iterations from its output bring it within decimetres
    assert g["model"] > 1.0 and g["refine"] < 0.05 * g["model"] and g["optimize"] < g["refine"]
    assert all(rows[m]["frames_per_s"] > 0 for m in rows) and rows["refine"]["metrics"]["limit_violation"]["mean"] == 0


def test_retarget_refine_writes_the_refined_motion(tmp_path, capsys, micro_checkpoint):  # noqa: F811
    src = synthetic_csv(tmp_path / "walk.csv", frames=60)
    base = ["retarget", str(src), "--source", "g1", "--target", "h1", "--model", str(micro_checkpoint), "--steps", "2"]
    assert main(base + ["-o", str(tmp_path / "a.csv")]) == 0
    assert main(base + ["-o", str(tmp_path / "b.csv"), "--refine", "5"]) == 0
    err = capsys.readouterr().err
    assert "diffusion+refine5" in err
    a, b = np.loadtxt(tmp_path / "a.csv", delimiter=","), np.loadtxt(tmp_path / "b.csv", delimiter=",")
    assert a.shape == b.shape and not np.allclose(a, b)
    assert main(["retarget", str(src), "--source", "g1", "--target", "h1", "--method", "optimize", "--refine", "3", "-o", str(tmp_path / "c.csv")]) == 1
    assert "--refine refines a model's output" in capsys.readouterr().err
