"""Where bfloat16 runs natively, and the autocast the network uses there.

bf16 autocast halves the network's time on CPUs with AMX (measured on a 2-core Xeon: one `mer-base`
evaluation of 16 windows 1.6-2.2 s in float32, 0.8-1.2 s in bf16, g-mpbpe within 0.2 mm;
docs/model.md) and on accelerators; without AMX or AVX512-BF16 PyTorch emulates it, several times
slower than float32, so callers warn there (:func:`native_bf16`).
"""

from __future__ import annotations

import contextlib
import functools
import logging
from pathlib import Path

import torch

__all__ = ["native_bf16", "network_autocast"]

log = logging.getLogger(__name__)


def native_bf16(device: str | torch.device = "cpu") -> bool:
    """Whether bfloat16 autocast runs natively on ``device``: always on accelerators; on the CPU only
    with AMX or AVX512-BF16 (oneDNN's check). Elsewhere PyTorch emulates it, several times slower
    than float32 (measured on an AVX2 machine: a ``base`` step 43 s in bf16, docs/model.md)."""
    if torch.device(device).type != "cpu":
        return True
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):  # a PyTorch without the check: the CPU's flags, where Linux lists them
        try:
            flags = Path("/proc/cpuinfo").read_text()
        except OSError:
            return True  # cannot tell: no warning
        return "amx_bf16" in flags or "avx512_bf16" in flags


def network_autocast(device: str | torch.device, bf16: bool) -> contextlib.AbstractContextManager:
    """bfloat16 autocast on ``device`` when ``bf16`` (with a warning where it is emulated), else nothing."""
    if not bf16:
        return contextlib.nullcontext()
    dev = torch.device(device)
    if not native_bf16(dev):
        _warn_emulated()
    return torch.autocast(dev.type, dtype=torch.bfloat16)


@functools.cache
def _warn_emulated() -> None:  # once per process, not once per network call
    log.warning("bf16 requested on a CPU without native bfloat16 (no AMX or AVX512-BF16): PyTorch emulates it, "
                "several times slower than float32 here; leave --bf16 off")  # fmt: skip
