"""The volume factor of a reduced-order model's force (manifest `force`).

    python -m tacrom_rom.force_factor DATA MODEL_DIR

On a bonded layer the total normal force is close to proportional to the surface's
displaced volume, with a constant of the gel and its grid that barely depends on the
indenter. `rom` reports the coarse gel's normal force scaled by the decoded surface's
displaced volume over the coarse one's, times this factor: the median, over the training
presses of DATA (a `tacrom gen-data` set that records forces; held-out families are left
out), of (F_ref / V_ref) / (F_coarse / V_coarse), which takes out the coarse grid's own
constant. Writes it into MODEL_DIR/manifest.json.
"""
from __future__ import annotations

import glob
import json
import os
import sys

import numpy as np

MIN_FORCE = 1e-3  # N: lighter presses carry round-off, not the grid's constant


def factor(path):
    with open(os.path.join(path, "dataset.json")) as f:
        ds = json.load(f)
    held_out = set(ds["held_out"])
    ratios = []
    for js in sorted(glob.glob(os.path.join(path, "sample-*.json"))):
        with open(js) as f:
            meta = json.load(f)
        if meta["family"] in held_out or not meta["reference"]["converged"]:
            continue
        fc = (meta["coarse"].get("force") or [0, 0, 0])[2]
        fr = (meta["reference"].get("force") or [0, 0, 0])[2]
        if fc < MIN_FORCE or fr < MIN_FORCE:
            continue
        a = np.load(js[:-5] + ".npy").astype(np.float64)
        vc, vr = a[0].sum(), a[2].sum()
        if vc > 0 and vr > 0:
            ratios.append((fr / vr) / (fc / vc))
    if not ratios:
        raise SystemExit(f"{path}: no training press with both forces recorded")
    r = np.array(ratios)
    return float(np.median(r)), len(r), float(np.percentile(r, 10)), float(np.percentile(r, 90)), ds


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2:
        raise SystemExit(__doc__)
    data, model = argv
    k, n, p10, p90, ds = factor(data)
    path = os.path.join(model, "manifest.json")
    with open(path) as f:
        m = json.load(f)
    m["force"] = {
        "volume_factor": round(k, 4),
        "presses": n,
        "percentiles_10_90": [round(p10, 4), round(p90, 4)],
        "reference_dx": ds.get("fine_dx"),
        "command": f"python -m tacrom_rom.force_factor {data} {model}",
    }
    with open(path, "w") as f:
        json.dump(m, f, indent=1)
    print(f"volume factor {k:.4f} over {n} training presses (10th to 90th percentile {p10:.4f} to {p90:.4f})")


if __name__ == "__main__":
    main()
