"""The presses of small footprint in a paired data set, as `tacrom gen-data --indices`
takes them: those whose rigid penetration (channel 1 of `sample-NNNNNN.npy`) is positive
at MIN to MAX lattice points (1 to 43 by default: footprints under about 4 mm^2 on the 0.3
mm lattice).

    python -m tacrom_rom.small DATA [--min 1] [--max 43]

prints the sample indices, comma-separated. Solving these again at a finer reference
spacing and overlaying them on the data (`tacrom_rom.train --reference`) replaces the
reference where the coarser one is furthest from converged: on footprints a few of its
cells across (docs/rom.md, "A narrower decoder").
"""
from __future__ import annotations

import argparse
import os

import numpy as np


def small_presses(path, lo=1, hi=43):
    """Sorted sample indices of DATA whose penetration is positive at lo..=hi lattice points."""
    out = []
    for f in sorted(os.listdir(path)):
        # sample-NNNNNN.npy only (not a press's sample-NNNNNN-pressure.npy)
        if not (f.startswith("sample-") and f.endswith(".npy") and f[7:13].isdigit() and len(f) == 17):
            continue
        n = int(np.count_nonzero(np.load(os.path.join(path, f), mmap_mode="r")[1] > 0.0))
        if lo <= n <= hi:
            out.append(int(f[7:13]))
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", metavar="DATA", help="a data directory written by `tacrom gen-data`")
    p.add_argument("--min", type=int, default=1, help="fewest penetrated lattice points (default 1)")
    p.add_argument("--max", type=int, default=43, help="most penetrated lattice points (default 43)")
    a = p.parse_args(argv)
    print(",".join(str(i) for i in small_presses(a.data, a.min, a.max)))


if __name__ == "__main__":
    main()
