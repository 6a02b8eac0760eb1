"""Merge paired data sets of the same gel size, lattice and solvers into one directory, for
training a model conditioned on the gel's material on presses of several materials.

    python -m tacrom_rom.merge OUT RANGED [FIXED ...]

RANGED is a data set that draws each sample's Poisson's ratio and friction from ranges
(`tacrom gen-data --poisson LO,HI --friction LO,HI`); its dataset.json becomes OUT's, with
`merged_from` listing the inputs. Each
FIXED data set (one material, such as `make gen-data`'s) adds its samples with indices
offset by 100000 * k and its material written into each sample's JSON; its material must
lie inside RANGED's ranges. RANGED may be a data set of one material too (other indenter
families of the same gel, `tacrom gen-data --families blob,stone,brick`): the FIXED ones
must then have its material. OUT's held-out families are those of every input. Files are
copied; OUT is created if needed.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil

KEYS = ("size", "lattice", "coarse_dx", "fine_dx", "pitch", "seed", "material", "young", "recipe")


def samples(path):
    for f in sorted(os.listdir(path)):
        if f.startswith("sample-") and f.endswith(".json") and os.path.exists(os.path.join(path, f[:-5] + ".npy")):
            yield int(f[7:13]), os.path.join(path, f[:-5])


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out", metavar="OUT", help="the merged data set's directory (created if needed)")
    p.add_argument("ranged", metavar="RANGED", help="the data set whose dataset.json becomes OUT's (materials drawn from ranges, or one material)")
    p.add_argument("fixed", metavar="FIXED", nargs="*", help="data sets of one material each, added with offset indices")
    a = p.parse_args(argv)
    out, ranged, fixed = a.out, a.ranged, a.fixed
    ds = json.load(open(os.path.join(ranged, "dataset.json")))
    held_out = list(ds.get("held_out", []))
    for path in fixed:
        for fam in json.load(open(os.path.join(path, "dataset.json"))).get("held_out", []):
            if fam not in held_out:
                held_out.append(fam)
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "dataset.json"), "w") as f:
        json.dump(dict(ds, merged_from=[ranged] + fixed, held_out=held_out), f, indent=1)
    n = 0
    for k, path in enumerate([ranged] + fixed):
        other = json.load(open(os.path.join(path, "dataset.json")))
        for key in KEYS:
            if other.get(key) != ds.get(key):
                raise SystemExit(f"{path}: dataset.json {key} = {other.get(key)!r}, {ranged} has {ds.get(key)!r}")
        material = None
        if k > 0:
            material = {"poisson": other["poisson"], "friction": other["friction"]}
            for name, v in material.items():
                lo, hi = ds.get(f"{name}_range") or [ds[name]] * 2
                if not lo <= v <= hi:
                    raise SystemExit(f"{path}: {name} {v} lies outside {ranged}'s range [{lo}, {hi}]")
        for i, stem in samples(path):
            j = i + 100000 * k
            meta = json.load(open(stem + ".json"))
            meta["index"] = j
            if material:
                meta.update(material)
            target = os.path.join(out, f"sample-{j:06d}")
            shutil.copy(stem + ".npy", target + ".npy")
            with open(target + ".json", "w") as f:
                json.dump(meta, f)
            n += 1
    print(f"{n} samples in {out}")


if __name__ == "__main__":
    main()
