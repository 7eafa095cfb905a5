"""Every hostile input class of issue 41, generated, run through mer in a fresh process, measured.

For each class the cases are generated from one small valid shard per format (synthetic motion, no
data needed), a loopback Hub that lies (``tests/hub_server.py``), planted symbolic links, or a
tmpfs that is too small (``unshare -rm``, skipped where user namespaces are not allowed). Each class
runs in its own interpreter (the Hub and disk-full cases one per case); before each case the peak
resident set (VmHWM) is reset, so the figures are per case. Printed: class, cases, outcome, and for
the worst case the peak RSS (whole process, imports included), its growth during the case, and
the time.

Outcomes: ``MerError`` (every case refused with mer's own error, naming the file; one class name
where all are the same), ``read unchanged`` (a flipped byte mer does not use: what was read equals
what was written, compared by a digest of every sample), ``refused``
(write redirections: the link refused and its target untouched), ``replaced`` (a link under an
output name replaced by the file, its target untouched), and for disk full ``DiskFullError`` (the
command prints it as one line and exits 1: ``tests/data/shards/test_disk_full.py``).
Anything else is printed as a failure (``NOT ...``), and the exit status is 1.

The classes of issue 51 (robots, meshes, motion capture, outputs, the viewer) are generated and run
by ``tools/hostile_robots.py`` (its docstring: outcomes ``resolved in its folder``, ``refused``,
``closed cleanly``) and printed in the same table; ``--only 41|51`` runs one set.

    python tools/hostile_inputs.py [--keep DIR] [--only 41|51]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parent)]

from hostile_hub import run_shards  # noqa: E402
from hostile_robots import run as run_robots  # noqa: E402
from hostile_robots import table  # noqa: E402

# ---- the table ---------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--keep", type=Path, help="generate the cases into this folder and keep them")
    ap.add_argument("--only", choices=["41", "51"], help="run the classes of one issue only")
    args = ap.parse_args(argv)
    root = Path(tempfile.mkdtemp(prefix="mer-hostile-")) if args.keep is None else args.keep
    root.mkdir(parents=True, exist_ok=True)
    results: dict[str, list[dict]] = {}
    try:
        if args.only != "51":
            results.update(run_shards(root / "41"))
        if args.only != "41":
            results.update(run_robots(root / "51"))
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)
    lines, bad = table(results)
    print(f"{'class':<36} {'cases':>5}  {'outcome':<40} {'worst peak RSS':>12} {'(growth)':>10} {'worst time':>10}")
    print("\n".join(lines))
    total = sum(len(r) for r in results.values())
    print(f"{total} cases in {len(results)} classes; {'all contained' if not bad else f'{bad} class(es) NOT contained'}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
