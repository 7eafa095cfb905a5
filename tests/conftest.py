"""Shared fixtures: where ../shared is, an isolated MER_HOME, the robots and data."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ROBOTS = ("g1", "h1", "h1_2", "atlas", "oli", "tron1", "talos", "valkyrie")


def pytest_configure(config) -> None:
    """Under ``pytest -n N`` (the README's test command) N worker processes share the cores: each runs
    torch, and the subprocesses its tests start, on one thread (two threads each on two cores spin
    against each other). On 2 cores the suite took 507 s in one process, 297 s in two workers."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        os.environ["OMP_NUM_THREADS"] = "1"
        import torch

        torch.set_num_threads(1)


def _shared() -> Path:
    return Path(os.environ.get("MER_SHARED", REPO.parent / "shared")).resolve()


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """``../shared`` (or ``$MER_SHARED``); tests that need it skip with the reason when it is absent."""
    d = _shared()
    if not d.is_dir():
        pytest.skip(f"shared data folder {d} is absent (set MER_SHARED to use another)")
    return d


@pytest.fixture(scope="session")
def shared_robots(shared_dir: Path) -> Path:
    d = shared_dir / "robots"
    if not (d / "keypoints.reference.json").is_file():
        pytest.skip(f"{d} has no robot files")
    return d


@pytest.fixture(scope="session")
def bandai(shared_dir: Path) -> list[Path]:
    """The Bandai Namco BVH clips of ``../shared/data/bvh/bandai1`` (CC BY-NC: read, never copied)."""
    d = shared_dir / "data" / "bvh" / "bandai1"
    files = sorted(d.glob("*.bvh"))
    if not files:
        pytest.skip(f"the Bandai Namco BVH clips are absent from {d}")
    return files


@pytest.fixture(scope="session")
def shared_wild_robots(shared_dir: Path) -> Path:
    """``../shared/robots-wild``: public URDFs as their makers publish them (folder/NAME.urdf)."""
    d = shared_dir / "robots-wild"
    if not (d / "SOURCES.md").is_file():
        pytest.skip(f"{d} has no robot files")
    return d


@pytest.fixture(scope="session")
def lafan1_dir(shared_dir: Path) -> Path:
    d = shared_dir / "data" / "lafan1"
    if not (d / "g1").is_dir() or not (d / "h1").is_dir():
        pytest.skip(f"LAFAN1 robot CSVs are absent from {d}")
    return d


@pytest.fixture(autouse=True)
def mer_home(tmp_path_factory, monkeypatch) -> Path:
    """Every test gets its own empty MER_HOME (user robots, caches)."""
    home = tmp_path_factory.mktemp("mer_home")
    monkeypatch.setenv("MER_HOME", str(home))
    return home


@pytest.fixture
def torch_one_thread():
    """torch on one thread for the test (what each dataset worker runs; restored after):
    :func:`mer_models.retarget.workers.one_thread`."""
    from mer_models.retarget.workers import one_thread

    with one_thread():
        yield


@pytest.fixture(autouse=True)
def _quiet_third_party():
    for name in ("yourdfpy", "trimesh", "pytorch_kinematics"):
        logging.getLogger(name).setLevel(logging.ERROR)
    yield


def pytest_terminal_summary(terminalreporter):
    """How many generated inputs each fuzzed parser took, and the slowest (tests/test_fuzz_parsers.py)."""
    try:
        from fuzz_stats import summary_lines
    except ImportError:
        return
    lines = summary_lines()
    if lines:
        terminalreporter.write_sep("-", "fuzz: every input loaded or raised MerError")
        for line in lines:
            terminalreporter.write_line(line)
