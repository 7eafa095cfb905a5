"""A new user's first hour: the default path is the documented one and says so, a long solve shows
progress, every run ends with its metrics, and ``mer --help`` starts without torch."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from mer_data.motion.lafan1 import write_lafan1_csv
from mer_data.robots.registry import load_robot
from mer_data.synthesis.walking import walking_motion
from mer_models.cli import main


def _clip(tmp_path, seconds: float = 3.0):
    path = tmp_path / "walk.csv"
    write_lafan1_csv(path, walking_motion("g1", seconds), robot=load_robot("g1"))
    return path


def test_the_default_path_is_the_optimiser_and_it_says_so(tmp_path, capsys):
    """docs/model.md §The default path: without --method, the optimiser with its physical terms."""
    out = tmp_path / "h1.csv"
    assert main(["retarget", str(_clip(tmp_path)), "--source", "g1", "--target", "h1", "-o", str(out), "--json"]) == 0
    cap = capsys.readouterr()
    assert "h1 (optimize: the default, the most accurate path" in cap.err
    report = json.loads(cap.out)
    assert report["method"] == "optimize" and report["frames"] == 91
    m = report["metrics"]
    assert m["g_mpbpe"] < 0.05 and m["limit_violation"] == 0 and m["floor_frames"] == 0 and m["speed_frames"] == 0
    # a model option without --method means the model (and says why)
    assert main(["retarget", str(_clip(tmp_path, 1.0)), "--source", "g1", "--target", "h1", "-o", str(out), "--refine", "2",
                 "--quiet"]) == 0  # fmt: skip
    assert "diffusion+refine2" in capsys.readouterr().err


def test_every_run_ends_with_a_metrics_table(tmp_path, capsys):
    assert main(["retarget", str(_clip(tmp_path)), "--source", "g1", "--target", "h1", "-o", str(tmp_path / "o.csv"), "--quiet"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("target"))
    assert lines[head].split()[:3] == ["target", "g_mpbpe[m]", "mpboe[rad]"] and "skate_median[m/s]" in lines[head]
    row = lines[head + 1].split()
    assert row[0] == "h1" and 0 < float(row[1]) < 0.05
    # the legend under the row: every column, named as in --json and docs/model.md
    from mer_models.retarget.columns import METRIC_COLUMNS

    assert [line.split()[0] for line in lines[head + 2:]] == [c.header for c in METRIC_COLUMNS]


def test_a_solve_reports_its_progress():
    from mer_models.retarget.clip import retarget_features, source_features
    from mer_models.solver.physics import PhysicsConfig
    from mer_models.solver.progress import solver_progress

    g1 = load_robot("g1")
    m = walking_motion("g1", 2.0)
    f = source_features(m.base_pos, m.base_quat, m.node_angles(g1.skeleton), g1.skeleton, 30.0)
    seen: list[tuple[str, int, int]] = []
    with solver_progress(lambda stage, done, total: seen.append((stage, done, total))):
        retarget_features(f, g1.skeleton, load_robot("h1").skeleton, method="optimize", physics=PhysicsConfig())
    stages = [s for s, _, _ in seen]
    assert stages[0] == "key frames" and "all frames" in stages
    assert all(0 <= d < t for _, d, t in seen)
    before = len(seen)
    res = retarget_features(f, g1.skeleton, load_robot("h1").skeleton, method="optimize")  # outside: no reports
    assert len(seen) == before and np.isfinite(res.motion.q).all()


def test_help_starts_without_torch():
    code = ("import sys; from mer_models.cli import build_parser; build_parser().format_help(); "
            "print(sorted(m for m in ('torch', 'scipy', 'h5py', 'mujoco', 'mcap') if m in sys.modules))")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_options_are_not_abbreviated_and_typos_get_the_subcommands_usage(capsys):
    import pytest

    for argv, want in ((["retarget", "x.csv", "--source", "g1", "--targt", "h1"], "did you mean --target or --targets?"),
                       (["shards", "build", "--input", "d", "--robot", "g1"], "did you mean --robots?"),
                       (["shards", "solve", "d", "--batchh", "3"], "did you mean --batch?")):  # fmt: skip
        with pytest.raises(SystemExit) as exc:
            main(argv)
        err = capsys.readouterr().err
        assert exc.value.code == 2 and want in err, err
        assert f"usage: mer {' '.join(argv[:2] if argv[0] == 'shards' else argv[:1])}" in err  # the subcommand's own usage
