"""The volume factor of a reduced-order model's force (manifest `force`).

    python -m tacrom_rom.force_factor DATA MODEL_DIR [--finer FINE_DATA FORCES_CSV]

On a bonded layer the total normal force is close to proportional to the surface's
displaced volume, with a constant of the gel and its grid that barely depends on the
indenter. `rom` reports the coarse gel's normal force scaled by the decoded surface's
displaced volume over the coarse one's, times this factor: the median, over the training
presses of DATA (a `tacrom gen-data` set that records forces; held-out families are left
out), of (F_ref / V_ref) / (F_coarse / V_coarse), which takes out the coarse grid's own
constant. Writes it into MODEL_DIR/manifest.json.

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


def factor(path):
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


def at(k, table, nu):
    """The factor at Poisson's ratio `nu`: `table` interpolated linearly and held beyond its
    ends, or `k` without one (as the sensor reads the manifest)."""
    if not table:
        return k
    t = np.array(table)
    return float(np.interp(nu, t[:, 0], t[:, 1]))


def label_of(model):
    """The method label `tacrom eval-rom` gives the model folder `model` (its name;
    `rom-default`'s is `rom`)."""
    name = os.path.basename(os.path.normpath(model))
    return "rom" if name == "rom-default" else name


def finer_scale(fine, forces_csv, label, k, table):
    """The scale of the factor (`k`, `table`) to FINE's finer reference through the decoded
    volumes of FORCES_CSV's rows of the model `label`: (median, presses, 10th and 90th
    percentile, FINE's reference spacing)."""
    with open(os.path.join(fine, "dataset.json")) as f:
        ds = json.load(f)
    held_out = set(ds["held_out"])
    with open(forces_csv) as f:
        rows = [r for r in csv.DictReader(f) if r["method"] == label]
    if not rows:
        raise SystemExit(f"{forces_csv}: no row of the model {label!r} (tacrom eval-rom --models MODEL_DIR --all)")
    scales = []
    for r in rows:
        if r["family"] in held_out:
            continue
        with open(os.path.join(fine, r["sample"][:-4] + ".json")) as f:
            meta = json.load(f)
        if not meta["reference"]["converged"]:
            continue
        fc = (meta["coarse"].get("force") or [0, 0, 0])[2]
        ff = (meta["reference"].get("force") or [0, 0, 0])[2]
        vc, vd = float(r["volume_coarse_m"]), float(r["volume_decoded_m"])
        if fc < MIN_FORCE or ff < MIN_FORCE or vc <= 0 or vd <= 0:
            continue
        scales.append(ff / (fc * vd / vc) / at(k, table, meta.get("poisson", ds["poisson"])))
    if not scales:
        raise SystemExit(f"{fine}: no training press with both forces recorded among {forces_csv}'s rows")
    s = np.array(scales)
    return float(np.median(s)), len(s), float(np.percentile(s, 10)), float(np.percentile(s, 90)), ds.get("fine_dx")


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
    p.add_argument("--finer", nargs=2, metavar=("FINE_DATA", "FORCES_CSV"),
                   help="scale the factor to FINE_DATA's finer reference through the model's decoded volumes in FORCES_CSV "
                        "(tacrom eval-rom --data FINE_DATA --models MODEL_DIR --all)")
    a = p.parse_args(argv)
    data, model = a.data, a.model
    k, n, p10, p90, ds, table = factor(data)
    command = f"python -m tacrom_rom.force_factor {data} {model}"
    finer = {}
    if a.finer:
        label = label_of(model)
        scale, fn, f10, f90, fine_dx = finer_scale(*a.finer, label, k, table)
        k, p10, p90 = k * scale, p10 * scale, p90 * scale
        table = [[nu, round(v * scale, 4)] for nu, v in table] if table else None
        command += f" --finer {a.finer[0]} {a.finer[1]}"
        finer = {"finer": {"scale": round(scale, 4), "presses": fn, "percentiles_10_90": [round(f10, 4), round(f90, 4)],
                           "reference_dx": fine_dx}}
        print(f"scaled by {scale:.4f} to the {fine_dx * 1e3:g} mm reference over {fn} presses "
              f"(10th to 90th percentile {f10:.4f} to {f90:.4f})")
    path = os.path.join(model, "manifest.json")
    with open(path) as f:
        m = json.load(f)
    m["force"] = {
        "volume_factor": round(k, 4),
        "presses": n,
        "percentiles_10_90": [round(p10, 4), round(p90, 4)],
        **({"by_poisson": table} if table else {}),
        "reference_dx": ds.get("fine_dx"),
        **finer,
        "command": command,
    }
    with open(path, "w") as f:
        json.dump(m, f, indent=1)
    print(f"volume factor {k:.4f} over {n} training presses (10th to 90th percentile {p10:.4f} to {p90:.4f})")
    if table:
        print("by Poisson's ratio: " + ", ".join(f"{nu}: {v}" for nu, v in table))


if __name__ == "__main__":
    main()
