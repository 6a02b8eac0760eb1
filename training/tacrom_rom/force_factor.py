"""The volume factor of a reduced-order model's force (manifest `force`).

    python -m tacrom_rom.force_factor DATA MODEL_DIR [--decoded FORCES_CSV]

On a bonded layer the total normal force is close to proportional to the surface's
displaced volume, with a constant of the gel and its grid that barely depends on the
indenter. `rom` reports the coarse gel's normal force scaled by the decoded surface's
displaced volume over the coarse one's, times this factor: the median, over the training
presses of DATA (a `tacrom gen-data` set that records forces; held-out families are left
out), of (F_ref / V_ref) / (F_coarse / V_coarse), which takes out the coarse grid's own
constant. Writes it into MODEL_DIR/manifest.json.

With `--decoded`, the model's own decoded volumes stand in for the reference's: the factor
is the median of F_ref / (F_coarse V_dec / V_coarse), which makes the force the sensor
reports (the coarse force times V_dec / V_coarse times the factor) the reference's in the
median of each bin, whatever volume the decoder restores. FORCES_CSV is the `forces.csv` of
`tacrom eval-rom --all --data DATA --models MODEL_DIR` (per press: the forces and the
coarse, decoded and reference volumes); presses whose decoded-over-coarse volume lies
outside VOLUME_RATIO, where the sensor reports the coarse force, are left out. Without it
the factor assumes the decoder restores the reference's volume, and a decoder that restores
more (the linear models at Poisson's ratios above the 0.43 they were trained at: 9 % more
at 0.49) reports a force too high by as much (docs/rom.md, "The force factor from the
decoded volume").

For a data set whose presses draw Poisson's ratio from a range (`tacrom gen-data --poisson
LO,HI`, or such a set merged with fixed ones), the constant depends on it: the linear coarse
gel's ratio rises from about 1.08 at 0.3 to 1.6 at 0.48, steeply above 0.44. The manifest then also gets
`by_poisson`, the median over each of POISSON_BINS equal bins of the range at the bin's
median Poisson's ratio, which the sensor interpolates linearly (and holds beyond the ends).
"""
from __future__ import annotations

import argparse
import csv
import glob
import json
import os

import numpy as np

MIN_FORCE = 1e-3  # N: lighter presses carry round-off, not the grid's constant
POISSON_BINS = 9
MIN_BIN = 10  # presses a bin needs for its median
VOLUME_RATIO = (0.25, 4.0)  # decoded over coarse volume the sensor uses (src/rom/mod.rs)


def decoded_volumes(csv_path, model):
    """{sample file name: (coarse volume, decoded volume)} of MODEL's rows of an eval-rom
    `forces.csv` (the method column is the model folder's name)."""
    name = os.path.basename(os.path.normpath(model))
    out = {}
    with open(csv_path) as f:
        for row in csv.DictReader(f):
            if row["method"] == name:
                out[os.path.basename(row["sample"])] = (float(row["volume_coarse_m"]), float(row["volume_decoded_m"]))
    if not out:
        raise SystemExit(f"{csv_path}: no rows of method '{name}' (run tacrom eval-rom --all --models {model})")
    return out


def factor(path, decoded=None):
    """The median factor over DATA's training presses, their count, 10th and 90th
    percentiles, the data set's description and the table per Poisson's ratio; with
    `decoded` ({sample file: (V_coarse, V_dec)}, `decoded_volumes`) from the decoded volumes,
    over the presses it lists."""
    with open(os.path.join(path, "dataset.json")) as f:
        ds = json.load(f)
    held_out = set(ds["held_out"])
    ratios, poisson = [], []
    for js in sorted(glob.glob(os.path.join(path, "sample-*.json"))):
        with open(js) as f:
            meta = json.load(f)
        if meta["family"] in held_out or not meta["reference"]["converged"]:
            continue
        fc = (meta["coarse"].get("force") or [0, 0, 0])[2]
        fr = (meta["reference"].get("force") or [0, 0, 0])[2]
        if fc < MIN_FORCE or fr < MIN_FORCE:
            continue
        if decoded is not None:
            v = decoded.get(os.path.basename(js[:-5] + ".npy"))
            if v is None or not v[0] > 0 or not VOLUME_RATIO[0] <= v[1] / v[0] <= VOLUME_RATIO[1]:
                continue
            ratios.append(fr / (fc * v[1] / v[0]))
            poisson.append(meta.get("poisson", ds["poisson"]))
            continue
        a = np.load(js[:-5] + ".npy").astype(np.float64)
        vc, vr = a[0].sum(), a[2].sum()
        if vc > 0 and vr > 0:
            ratios.append((fr / vr) / (fc / vc))
            poisson.append(meta.get("poisson", ds["poisson"]))
    if not ratios:
        raise SystemExit(f"{path}: no training press with both forces recorded")
    r = np.array(ratios)
    return float(np.median(r)), len(r), float(np.percentile(r, 10)), float(np.percentile(r, 90)), ds, \
        by_poisson(np.array(poisson), r, ds.get("poisson_range"))


def by_poisson(nu, r, bounds):
    """[[Poisson's ratio, factor], ...] over the bins of `bounds` that hold MIN_BIN presses
    (None for a data set of one Poisson's ratio)."""
    if not bounds or bounds[1] <= bounds[0]:
        return None
    edges = np.linspace(bounds[0], bounds[1], POISSON_BINS + 1)
    table = []
    for k in range(POISSON_BINS):
        last = k == POISSON_BINS - 1
        inside = (nu >= edges[k]) & ((nu <= edges[k + 1]) if last else (nu < edges[k + 1]))
        if inside.sum() >= MIN_BIN:
            table.append([round(float(np.median(nu[inside])), 4), round(float(np.median(r[inside])), 4)])
    return table if len(table) >= 2 else None


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", metavar="DATA", help="paired data set (tacrom gen-data) whose training presses give the factor")
    p.add_argument("model", metavar="MODEL_DIR", help="model directory whose manifest.json receives the `force` section")
    p.add_argument("--decoded", metavar="FORCES_CSV",
                   help="eval-rom's forces.csv for DATA (--all) and MODEL_DIR: the factor from the model's decoded volumes")
    a = p.parse_args(argv)
    data, model = a.data, a.model
    decoded = decoded_volumes(a.decoded, model) if a.decoded else None
    k, n, p10, p90, ds, table = factor(data, decoded)
    path = os.path.join(model, "manifest.json")
    with open(path) as f:
        m = json.load(f)
    m["force"] = {
        "volume_factor": round(k, 4),
        "presses": n,
        "percentiles_10_90": [round(p10, 4), round(p90, 4)],
        **({"by_poisson": table} if table else {}),
        "reference_dx": ds.get("fine_dx"),
        **({"volumes": "decoded"} if decoded is not None else {}),
        "command": f"python -m tacrom_rom.force_factor {data} {model}"
        + (f" --decoded {a.decoded}" if a.decoded else ""),
    }
    with open(path, "w") as f:
        json.dump(m, f, indent=1)
    print(f"volume factor {k:.4f} over {n} training presses (10th to 90th percentile {p10:.4f} to {p90:.4f})")
    if table:
        print("by Poisson's ratio: " + ", ".join(f"{nu}: {v}" for nu, v in table))


if __name__ == "__main__":
    main()
