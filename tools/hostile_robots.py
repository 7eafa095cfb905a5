"""The hostile classes of issue 51 (robots, meshes, motion capture, outputs, the viewer), generated,
run through mer in fresh processes and measured; ``tools/hostile_inputs.py`` prints them with the
shard classes of issue 41. Run alone: ``python tools/hostile_robots.py [--tree DIR] [--cap-mib N]``.

Each class runs in its own interpreter: ``mer`` commands through ``mer_models.cli.main`` in-process
(exit status and stderr recorded), readers through the function every command reads with. Before
each case the peak resident set is reset (``/proc/self/clear_refs``), so the peak is per case
(whole process, imports included). After each case the parent checks what the case must leave: no
new file outside the case's own output (``NOT contained``), no output half-written, the files a
case must not change unchanged, the registry holding no outside text. Outcomes: the error class
(``MerError``: mer's error, exit 1, one line, no traceback), ``resolved in its folder`` (an
``<asset><model>`` registered from its own folder, whatever the working directory), ``refused``
(a websocket handshake from another origin), ``closed cleanly`` (SIGTERM). Anything else is a
failure (``NOT ...``).

``--tree DIR`` runs another checkout (the "before" table); ``--cap-mib N`` caps each probe's
address space (``prlimit --as``) so a bomb of an unfixed tree dies instead of taking the machine.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import hostile_sources as hs  # noqa: E402

PROBE = r'''
import io, json, os, sys, time, traceback, contextlib
def status(key):
    return int(next(l for l in open("/proc/self/status") if l.startswith(key)).split()[1]) * 1024
def reset_peak():
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass
import numpy as np
import torch  # noqa: F401 -- the imports every mer command has, before the baseline
from mer_data.base.errors import MerError
from mer_models.cli import main

def act(kind, a):
    if kind == "cli":
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            rc = main(a["argv"])
        text = err.getvalue()
        lines = [l for l in text.splitlines() if l.startswith("error:")]
        if rc == 1 and lines and "Traceback" not in text:
            return "MerError", lines[0][:300]
        return ("ok" if rc == 0 else f"NOT exit {rc}"), text[-300:]
    if kind == "source":
        from mer_data.motion.sources import read_source
        from mer_data.robots.registry import load_robot
        src = "bvh" if a["source"] == "bvh" else load_robot(a["source"])
        read_source(a["path"], src, fps=a.get("fps", 30.0))
    elif kind == "mesh":
        from mer_models.export.geometry import _read_mesh
        _read_mesh(__import__("pathlib").Path(a["path"]))
    elif kind == "bvh_keypoints":
        from mer_data.motion.sources import load_bvh_keypoints
        load_bvh_keypoints(a["path"])
    elif kind == "origin":
        return origin_case(a)
    else:
        raise ValueError(kind)
    return "ok", ""

def origin_case(a):
    import viser
    from websockets.sync.client import connect
    from websockets.exceptions import InvalidStatus
    from mer_data.kinematics.rotations import quat_to_matrix
    from mer_data.robots.registry import load_robot
    from mer_models.export.geometry import robot_meshes
    from mer_models.export.viewer import serve_motion
    from mer_models.export.writers import TargetMotion
    from mer_models.training.synthetic import synthetic_motion
    g1 = load_robot("g1")
    m = synthetic_motion(g1.skeleton, 10, seed=1)
    motion = TargetMotion(g1.skeleton, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())
    with serve_motion(motion, robot=g1, meshes=robot_meshes(g1, visual=False), port=0, play=False) as v:
        port = int(v.url.rsplit(":", 1)[1].strip("/"))
        def opened(origin):
            try:
                with connect(f"ws://127.0.0.1:{port}", origin=origin, subprotocols=[f"viser-v{viser.__version__}"],
                             open_timeout=10) as ws:
                    ws.recv(timeout=10)
                    return True
            except InvalidStatus:
                return False
        evil, own = opened(a["origin"]), opened(f"http://127.0.0.1:{port}")
    if evil:
        return "NOT refused: a page of " + a["origin"] + " received the scene", ""
    return ("refused" if own else "NOT: its own page refused too"), ""

out = []
for case in json.loads(sys.argv[1]):
    env = case.get("env", {})
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    here = os.getcwd()
    if case.get("cwd"):
        os.chdir(case["cwd"])
    reset_peak()
    base, t = status("VmRSS"), time.perf_counter()
    try:
        outcome, msg = act(case["action"], case["args"])
    except MerError as exc:
        outcome, msg = type(exc).__name__, str(exc).splitlines()[0]
    except BaseException as exc:
        outcome, msg = "NOT A MerError: " + type(exc).__name__, traceback.format_exc()[-600:]
    os.chdir(here)
    for k, v in old.items():
        os.environ.pop(k) if v is None else os.environ.__setitem__(k, v)
    out.append({"label": case["label"], "outcome": outcome, "message": msg[:300], "s": time.perf_counter() - t,
                "peak": status("VmHWM"), "growth": max(status("VmHWM") - base, 0)})
    print("CASE " + json.dumps(out[-1]), flush=True)
print("RESULT " + json.dumps(out))
'''


def probe(cases: list[dict], tree: Path, cap_mib: int | None = None, wrap: list[str] | None = None,
          timeout: float = 900) -> list[dict]:  # fmt: skip
    """Run ``cases`` in one fresh interpreter on checkout ``tree`` (a case that kills it: its row says so)."""
    env = {**os.environ, "PYTHONPATH": f"{tree}:{ROOT / 'tests'}", "MER_HOME": str(Path(cases[0]["home"]))}
    cmd = [sys.executable, "-c", PROBE, json.dumps(cases)]
    if cap_mib:
        cmd = ["prlimit", f"--as={cap_mib << 20}", *cmd]
    try:
        r = subprocess.run((wrap or []) + cmd, env=env, capture_output=True, text=True, timeout=timeout, cwd=tree)  # not this checkout
        stdout, died = r.stdout, f"rc {r.returncode}: {r.stderr[-200:]}"
    except subprocess.TimeoutExpired as exc:
        stdout = (exc.stdout or b"").decode() if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        died = f"killed after {timeout:.0f} s"
    done = {}
    for line in stdout.splitlines():
        if line.startswith("CASE "):
            row = json.loads(line[5:])
            done[row["label"]] = row
    rows = []
    for c in cases:  # the cases after one that killed the interpreter run again, each alone
        if c["label"] in done:
            rows.append(done[c["label"]])
        elif not rows or rows[-1]["label"] in done or len(cases) == 1:
            rows.append({"label": c["label"], "outcome": f"NOT A MerError: process died ({died})", "message": "",
                         "s": timeout if "killed" in died else 0, "peak": (cap_mib or 0) << 20, "growth": 0})  # fmt: skip
            rest = [x for x in cases if x["label"] not in done and x is not c]
            if rest:
                return rows + probe(rest, tree, cap_mib, wrap, timeout)
    return rows


def _digest(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else ""


def _files(root: Path) -> set[Path]:
    return {p for p in root.rglob("*")} if root.exists() else set()


def cases(root: Path) -> dict[str, list[dict]]:
    """Every class of issue 51: name -> cases (label, action, args, home, and what to check after)."""
    home = root / "home"
    out: dict[str, list[dict]] = {}

    def reg(cls: str, label: str, path: Path, fmt: str = "mjcf", **kw) -> None:
        name = "r" + hashlib.sha1(label.encode()).hexdigest()[:6]
        argv = ["robots", "register", name, f"--{fmt}", str(path), *kw.pop("extra", [])]
        out.setdefault(cls, []).append({"label": label, "action": "cli", "args": {"argv": argv}, "home": str(home),
                                        "robot": name, **kw})  # fmt: skip

    c = "MJCF expansion bombs"
    reg(c, "3 nested replicate count=1000 (573 B)", hs.replicate_bomb(root / "rep"))
    reg(c, "flexcomp grid 1000 x 1000 x 100", hs.flexcomp_bomb(root / "flex"))
    reg(c, "2 nested replicates of a jointed body", hs.jointed_replicate(root / "jrep"))
    reg(c, "10,000 geoms written out", hs.many_geoms(root / "geoms"))
    c = "MJCF files outside its folder"
    for kind in ("include-abs", "include-up", "include-passwd", "meshdir-abs", "mesh-abs", "mesh-up", "mesh-link"):
        reg(c, kind, hs.outside_mjcf(root / "out" / kind / "model", kind, root / "out" / kind / "outside"), secret=True)
    c = "MJCF <model> and the working dir"
    reg(c, "another sub.xml in the working directory", hs.model_asset(root / "ma" / "model", root / "ma" / "cwd"),
        cwd=str(root / "ma" / "cwd"), own_joint="p_own_joint")  # fmt: skip
    reg(c, "model file ../cwd/sub.xml", hs.model_asset(root / "mb" / "model", root / "mb" / "cwd", outside=True),
        cwd=str(root / "mb" / "cwd"))  # fmt: skip
    c = "zip-bomb meshes"
    reg(c, "collision mesh m.zip (1 GB inflated)", hs.urdf(root / "zip1", mesh="m.zip"), "urdf")
    hs.zip_mesh(root / "zip1" / "m.zip")
    reg(c, "zip named m.stl", hs.urdf(root / "zip2", mesh="m.stl"), "urdf")
    hs.zip_mesh(root / "zip2" / "m.stl", 256 << 20)
    (root / "zip3").mkdir()
    (root / "zip3" / "m.stl.gz").write_bytes(hs.gzip_bytes(256 << 20))
    reg(c, "gzip mesh m.stl.gz", hs.urdf(root / "zip3", mesh="m.stl.gz"), "urdf")
    out[c].append({"label": "mer view's reader: m.zip", "action": "mesh", "args": {"path": str(root / "zip1" / "m.zip")},
                   "home": str(home)})  # fmt: skip

    c = "BVH / CSV amplification"
    src = lambda label, p, s="bvh", **kw: {"label": label, "action": "source", "args": {"path": str(p), "source": s, **kw},  # noqa: E731
                                           "home": str(home)}  # fmt: skip
    (root / "bvh").mkdir()
    out[c] = [src("960 CHANNELS 0 joints, 50,000 frames", hs.zero_channel_bvh(root / "bvh" / "zero.bvh")),
              src("Frame Time: 10", hs.slow_bvh(root / "bvh" / "slow.bvh")),
              src("Frame Time: 1000", hs.slow_bvh(root / "bvh" / "slower.bvh", "1000", 40)),
              src("30 MiB BVH (under the cap), bad last value", hs.big_bvh(root / "bvh" / "big30.bvh", 30)),
              src("200 MiB BVH", hs.big_bvh(root / "bvh" / "big200.bvh", 200)),
              src("--fps 0.001 on a CSV", hs.g1_csv(root / "bvh" / "g1.csv"), "g1", fps=0.001)]  # fmt: skip
    c = "numbers Python reads, formats do not"
    for label, text, where in (("URDF limit -1_0", "-1_0", "limit"), ("URDF limit full-width \uff11", "-\uff11", "limit"),
                               ("URDF origin 0.\u0661 (Arabic-Indic digit)", "0.\u0661", "origin")):  # fmt: skip
        reg(c, label, hs.odd_number_urdf(root / "num" / str(len(out.get(c, []))), text, where), "urdf")
    for label, text in (("CSV cell 1_0", "1_0"), ("CSV cell full-width \uff11\uff10", "\uff11\uff10"), ("CSV cell infinity", "infinity")):
        p = hs.g1_csv(root / "num" / f"{len(out[c])}.csv", cell=(3, 9, text))
        out[c].append(src(label, p, "g1"))
    mj = hs.mjcf(root / "num" / "mj", hs.BODY.format('<replicate count="1_0"><geom size=".1"/></replicate>'))
    reg(c, "MJCF replicate count=1_0", mj)
    c = "duplicate keys in key-point files"
    (root / "dup").mkdir()
    out[c] = [{"label": "BVH key points JSON", "action": "bvh_keypoints", "home": str(home),
               "args": {"path": str(hs.duplicate_keys(root / "dup" / "k.json"))}},
              {"label": "BVH key points YAML", "action": "bvh_keypoints", "home": str(home),
               "args": {"path": str(hs.duplicate_keys(root / "dup" / "k.yaml", "yaml"))}}]  # fmt: skip
    (root / "dup" / "r.json").write_text('{"left_toe": {"link": "a", "offset": [0, 0, 0]}, "left_toe": null}\n')
    reg(c, "robot key points JSON", hs.urdf(root / "dup"), "urdf", extra=["--keypoints", str(root / "dup" / "r.json")])
    c = "outputs mer did not write"
    build = ["shards", "build", "--synthetic", "1", "--robots", "g1", "--targets", "g1", "--augment", "0", "--split", "all"]
    for label, name, text in (("--out DIR with the project's README.md", "README.md", "# my project\n"),
                              ("--out DIR with another mer_meta.json", "mer_meta.json", '{"mine": 1}\n')):  # fmt: skip
        d = root / "own" / name
        d.mkdir(parents=True)
        (d / name).write_text(text)
        out.setdefault(c, []).append({"label": label, "action": "cli", "args": {"argv": [*build, "--out", str(d)]},
                                      "home": str(home), "unchanged": {str(d / name): _digest(d / name)}})  # fmt: skip
    return out


def readonly_cases(root: Path, ro: Path) -> list[dict]:
    """Unwritable outputs: ``ro`` is a read-only mount in the probe's namespace."""
    home = root / "home"
    csv = hs.g1_csv(root / "w" / "g1.csv")
    (root / "w" / "file").write_text("x\n")
    build = ["shards", "build", "--synthetic", "1", "--robots", "g1", "--targets", "g1", "--augment", "0", "--split", "all"]
    retarget = ["retarget", str(csv), "--source", "g1", "--target", "g1"]
    return [dict(c, home=str(home)) for c in [
        {"label": "retarget -o into a read-only folder", "action": "cli", "args": {"argv": [*retarget, "-o", str(ro / "o.csv")]}},
        {"label": "shards build --out in a read-only place", "action": "cli", "args": {"argv": [*build, "--out", str(ro / "s")]}},
        {"label": "register with a read-only MER_HOME", "action": "cli", "env": {"MER_HOME": str(ro)},
         "args": {"argv": ["robots", "register", "ro", "--urdf", str(hs.urdf(root / "w" / "u"))]}},
        {"label": "shards build --out naming a file", "action": "cli", "args": {"argv": [*build, "--out", str(root / "w" / "file")]}},
        {"label": "retarget -o naming a folder", "action": "cli", "args": {"argv": [*retarget, "-o", str(root / "w")]}},
    ]]  # fmt: skip


def sigterm_case(root: Path, tree: Path) -> dict:
    """``mer view`` ended by SIGTERM with a client connected: exit 0 and a close frame, or a failure."""
    import viser
    from websockets.exceptions import ConnectionClosedOK
    from websockets.sync.client import connect

    csv = hs.g1_csv(root / "view" / "g1.csv", frames=30)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "PYTHONPATH": str(tree), "MER_HOME": str(root / "home")}
    p = subprocess.Popen([sys.executable, "-c", "import sys; from mer_models.cli import main; sys.exit(main())", "view", str(csv), "--robot", "g1", "--port", str(port),
                          "--paused", "--collision"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tree)  # fmt: skip
    t0, row = time.perf_counter(), {"label": "SIGTERM with a client connected", "peak": 0, "growth": 0, "message": ""}
    try:
        line = ""
        while "viewing" not in line:  # viser prints its banner first
            line = p.stdout.readline()
            if not line:
                raise RuntimeError(f"mer view did not start (exit {p.wait(timeout=20)}): {p.stderr.read()[-300:]}")
        port = int(line.split("http://127.0.0.1:", 1)[1].split()[0].strip("/"))  # the port it took
        with connect(f"ws://127.0.0.1:{port}", origin=f"http://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"],
                     open_timeout=20) as ws:  # fmt: skip
            ws.recv(timeout=20)
            p.send_signal(signal.SIGTERM)
            try:
                while True:
                    ws.recv(timeout=20)
            except ConnectionClosedOK:
                clean = True
            except Exception:  # noqa: BLE001 - closed without a close frame, or not closed
                clean = False
        rc = p.wait(timeout=20)
        err = p.stderr.read()
        ok = clean and rc == 0 and "Traceback" not in err
        row["outcome"] = "closed cleanly" if ok else f"NOT clean: close frame {clean}, exit {rc}"
        row["message"] = err[-200:]
    except Exception as exc:  # noqa: BLE001 - reported as the row's failure
        row["outcome"] = f"NOT clean: {type(exc).__name__}: {exc}"[:200]
    finally:
        if p.poll() is None:
            p.kill()
    row["s"] = time.perf_counter() - t0
    return row


def run(root: Path, tree: Path = ROOT, cap_mib: int | None = None) -> dict[str, list[dict]]:
    """Generate every class under ``root``, run it on checkout ``tree``, check the leftovers."""
    results: dict[str, list[dict]] = {}
    for cls, cs in cases(root).items():
        before = _files(root)
        rows = []
        for case, row in zip(cs, [r for c in cs for r in probe([c], tree, cap_mib, timeout=300)]):
            rows.append(_verify(root, case, row, before))
        results[cls] = rows
    results["viewer websocket Origin"] = probe([{"label": "Origin: http://evil.example.com", "action": "origin",
                                                  "args": {"origin": "http://evil.example.com"}, "home": str(root / "home")}],
                                                tree, cap_mib)  # fmt: skip
    results["viewer websocket Origin"].append(sigterm_case(root, tree))
    results["unwritable outputs"] = readonly(root, tree, cap_mib)
    return results


def _verify(root: Path, case: dict, row: dict, before: set[Path]) -> dict:
    """The case's row, failed where it wrote outside, half-wrote, changed a file or registered outside text."""
    if row["outcome"].startswith("NOT"):
        return row
    home = Path(case["home"]) / "robots" / case.get("robot", "-")
    if case.get("own_joint"):  # resolved in its own folder: the model's joint, not the working directory's
        text = " ".join(p.read_text(errors="replace") for p in home.glob("*.xml")) if home.is_dir() else ""
        stored = [p.name for p in home.glob("model-*.xml")] if home.is_dir() else []
        if row["outcome"] != "ok":
            return row
        row["outcome"] = ("resolved in its folder" if "own_joint" in text and "CWD_JOINT" not in text and stored
                          else "NOT: the working directory's sub.xml (or an outside path) registered")  # fmt: skip
        return row
    if row["outcome"] == "ok":
        row["outcome"] = "NOT refused: exit 0"
        if case.get("secret") and home.is_dir() and any(x in p.read_text(errors="replace") for x in ("SECRET", "7.125")
                                                        for p in home.glob("*") if p.is_file()):  # fmt: skip
            row["outcome"] = "NOT contained: the outside file is in the registry"
        return row
    for path, digest in case.get("unchanged", {}).items():
        if _digest(Path(path)) != digest:
            row["outcome"] = f"NOT contained: {Path(path).name} changed"
    new = [p for p in _files(root) - before if "home" not in p.parts and ".lock" not in p.name]
    if new:
        row["outcome"] = f"NOT contained: wrote {new[0]}"
    if home.is_dir() and case.get("robot"):
        row["outcome"] = f"NOT contained: registered {home}"
    return row


def readonly(root: Path, tree: Path, cap_mib: int | None) -> list[dict]:
    if shutil.which("unshare") is None:
        return [{"label": "skipped: no unshare(1)", "outcome": "skipped", "message": "", "s": 0, "peak": 0, "growth": 0}]
    ro = root / "ro"
    ro.mkdir()
    cs = readonly_cases(root, ro)
    script = f'mount -t tmpfs -o ro,size=64k tmpfs {ro} || exit 99; exec "$@"'
    before = _files(root)
    rows = probe(cs, tree, cap_mib, wrap=["unshare", "-rm", "sh", "-c", script, "sh"])
    return [_verify(root, c, r, before) for c, r in zip(cs, rows)]


def table(results: dict[str, list[dict]]) -> tuple[list[str], int]:
    """The printed rows (class, cases, outcome, worst peak, its growth, worst time) and the failing classes."""
    lines, bad = [], 0
    for name, rows in results.items():
        outcomes = sorted({r["outcome"] for r in rows})
        good = all(not o.startswith("NOT") and o not in ("ok",) for o in outcomes)
        bad += not good
        errors = [o for o in outcomes if o.endswith("Error") and not o.startswith("NOT")]
        shown = ", ".join((["MerError"] if len(errors) > 1 else errors) + [o for o in outcomes if o not in errors])
        worst = max(rows, key=lambda r: r["peak"])
        lines.append(f"{name:<36} {len(rows):>5}  {shown[:40]:<40} {worst['peak'] / 2**20:>8.0f} MiB "
                     f"{worst['growth'] / 2**20:>6.0f} MiB {max(r['s'] for r in rows):>8.2f} s")  # fmt: skip
        for r in rows:
            if r["outcome"].startswith("NOT") or r["outcome"] == "ok":
                lines.append(f"    {r['label']}: {r['outcome'][:120]} {r['message'][:160]!r}")
    return lines, bad


if __name__ == "__main__":
    import argparse
    import tempfile

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", type=Path, default=ROOT, help="the checkout to run (default: this one)")
    ap.add_argument("--cap-mib", type=int, help="address-space cap of each probe [MiB] (prlimit --as)")
    ap.add_argument("--keep", type=Path, help="generate the cases into this folder and keep them")
    a = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="mer-hostile51-")) if a.keep is None else a.keep
    work.mkdir(parents=True, exist_ok=True)
    try:
        res = run(work, a.tree.resolve(), a.cap_mib)
    finally:
        if a.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    rows, nbad = table(res)
    print(f"{'class':<36} {'cases':>5}  {'outcome':<40} {'worst peak RSS':>12} {'(growth)':>10} {'worst time':>10}")
    print("\n".join(rows))
    print(f"{sum(len(r) for r in res.values())} cases in {len(res)} classes; "
          f"{'all contained' if not nbad else f'{nbad} class(es) NOT contained'}")  # fmt: skip
    sys.exit(1 if nbad else 0)
