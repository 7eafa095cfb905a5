"""The last check before anything is written: every number of an output is finite.

A NaN or an infinity in a written file is never what a user wants (a model config with an infinite
scale, a diverged network, an overflowing input all produce them); writers call
:func:`require_finite` on everything they are about to write, and refuse with
:class:`~mer_data.base.errors.OutputError` instead: the output is not written at all.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from .errors import OutputError

__all__ = ["require_finite"]


def require_finite(arrays: Mapping[str, object], *, path: str | Path | None = None, what: str = "output") -> None:
    """Raise :class:`OutputError` naming the first array (and its first frame) that is not finite.

    Args:
        arrays: name → array-like (numpy or torch); non-float arrays are skipped.
        path: the file that would have been written (for the message).
        what: what is being written, e.g. ``"retargeted motion"``.
    """
    for name, value in arrays.items():
        a = np.asarray(value.detach().cpu() if hasattr(value, "detach") else value)
        if not np.issubdtype(a.dtype, np.floating) or a.size == 0:
            continue
        finite = np.isfinite(a)
        if finite.all():
            continue
        first = tuple(int(i) for i in np.argwhere(~finite)[0])
        raise OutputError(
            f"the {what} has {int((~finite).sum())} NaN/inf value(s) in {name!r} (first at index {first}); "
            "nothing was written",
            path=path,
            element=name,
            fix="check the inputs (model config, weights, robot description) for huge or non-finite numbers",
        )
