"""An unknown Hub id with no network fails fast, with one message (issues 40, 41).

"No network" is a closed loopback port as ``HF_ENDPOINT`` (connections refused at once), and
``HF_HUB_OFFLINE=1`` with an empty cache. Every Hub door of mer (a model by Hub id, a shard dataset
``hf://datasets/...``, motion input ``--input hf://...``) must give up within two seconds, without
retries, with one error and no warnings (the client's retries used to take 27 s and print every
warning twice).
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
_CASES = r"""
import json, logging, sys, time
records = []
class Count(logging.Handler):
    def emit(self, record):
        records.append(record.getMessage()[:200])
logging.getLogger().addHandler(Count(level=logging.WARNING))
from mer_data.base.errors import MerError
from mer_models import zoo  # imports first: the time measured is the Hub's
from mer_data.shards import ShardDataset
from mer_data.shards.sources import resolve_input
out = {}
def case(name, fn):
    records.clear()
    t = time.perf_counter()
    try:
        fn()
        err = None
    except MerError as exc:
        err = str(exc)
    except BaseException as exc:
        err = "NOT A MerError: " + type(exc).__name__ + ": " + str(exc)[:300]
    out[name] = {"s": time.perf_counter() - t, "error": err, "warnings": list(records)}
def model():
    zoo.load("someone/unknown-model")
def shards():
    ShardDataset("hf://datasets/someone/unknown-shards")
def motions():
    resolve_input("hf://someone/unknown-motions", ["g1"])
for name, fn in (("model", model), ("shards", shards), ("motions", motions)):
    case(name, fn)
print(json.dumps(out))
"""


def _closed_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now: connections are refused
    return port


def _env(tmp_path: Path, **extra: str) -> dict:
    base = {k: v for k, v in os.environ.items() if not k.startswith(("HF_", "HUGGINGFACE_"))}
    return {**base, "PYTHONPATH": str(REPO), "HF_HOME": str(tmp_path / "hf"), "HF_HUB_DISABLE_TELEMETRY": "1",
            "MER_HOME": str(tmp_path / "mer"), **extra}  # fmt: skip


@pytest.mark.parametrize("mode", ["closed port", "HF_HUB_OFFLINE"])
def test_unknown_hub_ids_fail_fast_with_one_message(tmp_path, mode):
    extra = {"HF_ENDPOINT": f"http://127.0.0.1:{_closed_port()}"}
    if mode == "HF_HUB_OFFLINE":
        extra["HF_HUB_OFFLINE"] = "1"
    r = subprocess.run([sys.executable, "-c", _CASES], env=_env(tmp_path, **extra), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]
    got = json.loads(r.stdout.strip().splitlines()[-1])
    for name, case in got.items():
        assert case["error"] and not case["error"].startswith("NOT A MerError"), (name, case)
        assert case["s"] < 2.0, (name, case)
        assert case["warnings"] == [], (name, case)
        assert ("HF_HUB_OFFLINE" if mode == "HF_HUB_OFFLINE" else "cannot") in case["error"], (name, case)


def test_the_command_prints_one_error_line(tmp_path):
    env = _env(tmp_path, HF_ENDPOINT=f"http://127.0.0.1:{_closed_port()}")
    r = subprocess.run([sys.executable, "-m", "mer_models", "shards", "build", "--input", "hf://someone/unknown", "--robots", "g1",
                        "--out", str(tmp_path / "out"), "--quiet"], env=env, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 1
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert len(lines) == 2 and lines[0].startswith("error: ") and lines[1].lstrip().startswith("fix: "), r.stderr
