"""Run zoo operations in a fresh interpreter, the way a user's process runs them.

huggingface_hub reads ``HF_ENDPOINT``, ``HF_HUB_CACHE``, ``HF_HUB_OFFLINE`` and ``HF_HUB_DISABLE_XET``
when it is imported, so the tests start this script with those variables already in the
environment (see :func:`run_worker`): the client's own configuration path is exercised, nothing in
huggingface_hub is patched. Usage::

    python tests/zoo_worker.py '[{"op": "download", "spec": "my-model"}, ...]'

Prints one JSON line: a list with, per operation, ``{"ok": true, "result": ...}`` or
``{"ok": false, "error": "<exception class>", "message": "..."}``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _op(spec: dict):
    from huggingface_hub import constants

    from mer_models import zoo
    from mer_models.zoo import hub
    from mer_models.zoo.integrity import sha256_file

    op = spec["op"]
    if op == "constants":
        return {"endpoint": constants.ENDPOINT, "cache": constants.HF_HUB_CACHE, "offline": constants.HF_HUB_OFFLINE,
                "disable_xet": constants.HF_HUB_DISABLE_XET}
    if op == "setenv":
        os.environ[spec["name"]] = spec["value"]
        return None
    if op == "download":
        res = zoo.resolve(spec["spec"], spec.get("revision"))
        return {"folder": str(res.folder), "revision": res.revision, "verified": res.verified, "source": res.source,
                "files": {p.name: sha256_file(p) for p in sorted(res.folder.iterdir())}}
    if op == "load":
        ckpt = zoo.load(spec["spec"], spec.get("revision"))
        return {"path": str(ckpt.path), "targets": ckpt.targets, "step": ckpt.step}
    if op == "publish":
        r = zoo.publish(spec["checkpoint"], name=spec["name"], repo_id=spec["repo_id"], base=spec.get("base"),
                        cards_dir=spec.get("cards_dir"), license=spec.get("license"))
        return {"commit": r.commit, "card_commit": r.card_commit, "card_path": str(r.card_path)}
    if op == "list":
        return [{"name": e.name, "where": zoo.where(e), "source": e.source} for e in zoo.list_models()]
    if op == "cached":
        p = hub.cached_file(spec["repo_id"], spec["filename"], spec["revision"])
        return str(p) if p else None
    raise ValueError(f"unknown op {op!r}")


def main(ops: list[dict]) -> list[dict]:
    out = []
    for spec in ops:
        try:
            out.append({"ok": True, "result": _op(spec)})
        except Exception as exc:  # reported to the test, which asserts on it
            out.append({"ok": False, "error": type(exc).__name__, "message": str(exc),
                        "mro": [c.__name__ for c in type(exc).__mro__]})
    return out


def run_worker(ops: list[dict], env: dict[str, str], timeout: float = 120.0) -> list[dict]:
    """Run ``ops`` in a fresh interpreter with exactly the HF_* variables of ``env``."""
    base = {k: v for k, v in os.environ.items() if not k.startswith(("HF_", "HUGGINGFACE_", "TRANSFORMERS_"))}
    base.update(env)
    base["PYTHONPATH"] = str(REPO) + os.pathsep + base.get("PYTHONPATH", "")
    proc = subprocess.run([sys.executable, str(Path(__file__)), json.dumps(ops)], env=base, capture_output=True,
                          text=True, timeout=timeout, cwd=str(REPO))
    if proc.returncode != 0 or not proc.stdout.strip():
        raise RuntimeError(f"zoo worker failed (rc {proc.returncode}):\n{proc.stderr[-4000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


if __name__ == "__main__":
    print(json.dumps(main(json.loads(sys.argv[1]))))
