"""Registry writes under concurrency and interruption: no registration lost, --force never loses the robot."""

from __future__ import annotations

import multiprocessing
import os
import shutil
import sys

import pytest
from urdf_factory import humanoid

from mer_data.base import atomic
from mer_data.base.atomic import owner_tag
from mer_data.base.errors import RobotExistsError
from mer_data.robots.register import register_robot
from mer_data.robots.registry import known_names, load_robot, robots_dir

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork and pids: Linux")
FORK = multiprocessing.get_context("fork")


@pytest.fixture(scope="module")
def urdfs(tmp_path_factory):
    d = tmp_path_factory.mktemp("urdf")
    out = {}
    for scale in (1.0, 1.2):
        f = d / f"bot{scale}.urdf"
        f.write_text(humanoid(scale=scale).xml())
        out[scale] = f
    return out


def _register(name, urdf, barrier, force=False):
    barrier.wait(30)
    try:
        register_robot(name, urdf, force=force)
    except BaseException as exc:  # noqa: BLE001 - reported through the exit status
        print(f"{name}: {exc!r}", file=sys.stderr)
        os._exit(1)
    os._exit(0)


def test_eight_concurrent_registrations_of_different_names_all_land(urdfs):
    names = [f"bot{i}" for i in range(8)]
    barrier = FORK.Barrier(len(names))
    procs = [FORK.Process(target=_register, args=(n, urdfs[1.0], barrier)) for n in names]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
    assert [p.exitcode for p in procs] == [0] * 8
    assert set(names) <= set(known_names())
    assert all(load_robot(n).skeleton.num_dof > 0 for n in names)
    assert not [p.name for p in robots_dir().iterdir() if p.name.startswith(".")]


def test_the_sweep_keeps_live_temporaries_and_removes_dead_ones(urdfs):
    root = robots_dir()
    root.mkdir(parents=True)
    live = root / f".tmp-other~{owner_tag()}~abc123"  # this process: alive
    live.mkdir()
    child = FORK.Process(target=os._exit, args=(0,))
    child.start()
    child.join()
    host = owner_tag().split("~")[0]
    dead = root / f".tmp-gone~{host}~{child.pid}~abc123"
    dead.mkdir()
    register_robot("bot", urdfs[1.0])
    assert live.is_dir() and not dead.exists()


def _die_between_renames(name, urdf):
    """--force through the two-rename path, killed (no cleanup at all) between the two renames."""
    calls = {"n": 0}
    real = os.rename

    def rename(a, b):
        calls["n"] += 1
        if calls["n"] == 3:  # 1: tmp -> final refused (exists), 2: final -> .old, 3: tmp -> final
            os._exit(9)
        return real(a, b)

    atomic._exchange = lambda a, b: False
    atomic.os.rename = rename
    register_robot(name, urdf, force=True)
    os._exit(0)


def test_a_kill_between_the_renames_of_force_does_not_lose_the_robot(urdfs):
    register_robot("bot", urdfs[1.0])
    before = load_robot("bot").skeleton.fingerprint
    p = FORK.Process(target=_die_between_renames, args=("bot", urdfs[1.2]))
    p.start()
    p.join(60)
    assert p.exitcode == 9
    assert not (robots_dir() / "bot").exists()  # the window the kill hit: the old folder is aside
    assert load_robot("bot").skeleton.fingerprint == before  # looked up by name: put back
    register_robot("bot", urdfs[1.2], force=True)  # and a later --force completes
    assert load_robot("bot").skeleton.fingerprint != before
    assert not [p.name for p in robots_dir().iterdir() if p.name.startswith(".")]


def _replace_many(urdf, n):
    for _ in range(n):
        register_robot("bot", urdf, force=True)
    os._exit(0)


def test_force_replacement_is_never_seen_half_done(urdfs):
    register_robot("bot", urdfs[1.0])
    card = robots_dir() / "bot" / "robot.yaml"
    p = FORK.Process(target=_replace_many, args=(urdfs[1.2], 6))
    p.start()
    misses = checks = 0
    while p.is_alive():
        checks += 1
        misses += not card.is_file()
    p.join()
    assert p.exitcode == 0 and checks > 100
    assert misses == 0


def test_a_name_taken_meanwhile_is_refused_not_overwritten(urdfs, monkeypatch, tmp_path):
    from mer_data.robots import registry

    register_robot("bot", urdfs[1.0])
    before = load_robot("bot").skeleton.fingerprint
    final = robots_dir() / "bot"
    shutil.copytree(final, tmp_path / "other")
    shutil.rmtree(final)
    real = registry.load_urdf

    def racing_load(path):  # another process registers "bot" while this one validates its copy
        if not final.exists():
            shutil.copytree(tmp_path / "other", final)
        return real(path)

    monkeypatch.setattr(registry, "load_urdf", racing_load)
    with pytest.raises(RobotExistsError, match="meanwhile"):
        register_robot("bot", urdfs[1.2])
    assert load_robot("bot").skeleton.fingerprint == before
    assert not [p.name for p in robots_dir().iterdir() if p.name.startswith(".")]
