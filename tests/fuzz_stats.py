"""Statistics of the fuzz suite (tests/test_fuzz_parsers.py), printed by conftest at the end of a run."""

from __future__ import annotations

#: parser -> {inputs, loaded, refused, slowest_s, slowest_input}
STATS: dict[str, dict] = {}


def summary_lines() -> list[str]:
    return [
        f"{name}: {s['inputs']} inputs ({s['loaded']} loaded, {s['refused']} refused with MerError), "
        f"slowest {s['slowest_s'] * 1000:.0f} ms on {s['slowest_input']}"
        for name, s in STATS.items()
    ]
