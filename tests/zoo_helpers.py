"""Helpers for the zoo tests: checkpoint folders and the environment of a client process."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from safetensors.numpy import save_file

TOKEN = "hf_loopback_test_token"


def make_checkpoint(folder: Path, *, seed: int = 0, dataset: str = "synthetic", targets=("g1", "h1"),
                    references=("g1",), step: int = 4, base_model: str | None = None) -> Path:
    """A checkpoint folder in mer's format (config.json + model.safetensors + optimizer state).

    The weights are random arrays (the zoo moves and verifies bytes; building the network is the
    model package's job and is tested where a trained checkpoint exists).
    """
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    data = {"dataset": dataset, "split": "all", "windows": 16}
    if base_model:
        data["base_model"] = base_model
    meta = {
        "format": "mer-checkpoint", "format_version": 1, "mer_version": "0.1.0", "created": "2026-01-01T00:00:00+00:00",
        "run": {"name": "tiny"},
        "robots": {"targets": {t: f"fp-{t}" for t in targets}, "references": {r: f"fp-{r}" for r in references}},
        "data": data, "metrics": {"train": {"loss": 0.25 + seed, "step": step}}, "step": step,
    }
    (folder / "config.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
    save_file({"layer.weight": rng.standard_normal((64, 48)).astype(np.float32),
               "layer.bias": rng.standard_normal(64).astype(np.float32)}, str(folder / "model.safetensors"))
    save_file({"state.0.exp_avg": np.zeros(3, np.float32)}, str(folder / "optimizer.safetensors"))
    return folder


def client_env(hub_url: str, tmp: Path, mer_home: Path, **extra: str) -> dict[str, str]:
    """The environment of a user's process pointed at the loopback Hub, with its own caches."""
    env = {
        "HF_ENDPOINT": hub_url,
        "HF_HOME": str(tmp / "hf_home"),
        "HF_HUB_CACHE": str(tmp / "hub_cache"),
        "HF_HUB_DISABLE_XET": "1",  # the loopback Hub does not speak Xet; uploads take the LFS path
        "HF_TOKEN": TOKEN,
        "MER_HOME": str(mer_home),
    }
    env.update(extra)
    return env
