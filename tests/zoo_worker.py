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
    from mer_models.hub import client as hub
    from mer_models.hub.integrity import sha256_file

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
    if op == "from_pretrained":
        from mer_models import RetargetModel

        m = RetargetModel.from_pretrained(spec["spec"], revision=spec.get("revision"), cache_dir=spec.get("cache_dir"),
                                          local_files_only=spec.get("local_files_only", False))
        if spec.get("save"):
            import numpy as np

            np.save(spec["save"], model_outputs(m))
        info = m.pretrained_info
        return {"source": info.source, "repo_id": info.repo_id, "revision": info.revision, "folder": str(info.folder),
                "step": info.step, "targets": sorted(info.robots["targets"])}
    if op == "push_to_hub":
        from mer_models import RetargetModel

        return {"commit": RetargetModel.from_pretrained(spec["spec"]).push_to_hub(spec["repo_id"], private=spec.get("private", False))}
    if op == "hub_card":  # the card as huggingface_hub reads it, after the Hub's validation
        from huggingface_hub import ModelCard as HubModelCard

        card = HubModelCard.load(spec["repo_id"])
        card.validate()
        return card.data.to_dict()
    if op == "upload_folder":  # a push by other tools (e.g. a partial or corrupted checkpoint)
        from huggingface_hub import HfApi

        api = HfApi()
        api.create_repo(spec["repo_id"], exist_ok=True)
        return api.upload_folder(folder_path=spec["folder"], repo_id=spec["repo_id"]).oid
    if op == "cached":
        p = hub.cached_file(spec["repo_id"], spec["filename"], spec["revision"])
        return str(p) if p else None
    raise ValueError(f"unknown op {op!r}")


def model_outputs(model):
    """The denoiser's output on a fixed batch and noise (G1 -> G1, H1): equal models give equal arrays."""
    import torch

    sys.path.insert(0, str(REPO / "tests"))
    from model_helpers import mixed_batch

    torch.manual_seed(0)
    batch = mixed_batch(("g1", "h1"))
    with torch.no_grad():
        cond = model.conditions(batch)
        x = torch.randn(cond.shape)
        return model.denoise(x, 0.5, cond).numpy()


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
