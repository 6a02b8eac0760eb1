"""A trained model's validation pairs from data sets of one gel each.

    python -m tacrom_rom.validate MODEL_DIR DATA [DATA ...] [--per-family N]

Each DATA is a validation set of one gel of the family (`tacrom gen-data --gel-family
--gel-size X,Y,T --held-out-only`). Replaces MODEL_DIR's `validation/` pairs with N held-out
presses of each family from each set (as `train --validation` does at the end of training)
and records each set's metrics, gel and command in the manifest's `validation.gels`.
"""
from __future__ import annotations

import argparse
import json
import os

import torch

from . import data as D
from .model import Autoencoder, hidden_of
from .train import validation_sets


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", help="model directory (manifest.json, weights.pt)")
    p.add_argument("data", nargs="+", help="validation sets of one gel each")
    p.add_argument("--per-family", type=int, default=1, help="held-out pairs of each family from each set")
    a = p.parse_args(argv)
    path = os.path.join(a.model, "manifest.json")
    with open(path) as f:
        manifest = json.load(f)
    lattice = manifest["lattice"]
    spec = D.Spec(size=tuple(lattice["size"]), nx=lattice["nx"], ny=lattice["ny"],
                  conditioning=manifest.get("conditioning"))
    model = Autoencoder(spec.encoder_len, spec.query_len, spec.coarse_index, manifest["latent"],
                        hidden_of(manifest))
    model.load_state_dict(torch.load(os.path.join(a.model, "weights.pt"), weights_only=True))
    model.eval()
    manifest.setdefault("validation", {})["gels"] = validation_sets(
        model, spec, a.data, a.model, a.per_family, spec.conditioning)
    with open(path, "w") as f:
        json.dump(manifest, f, indent=1)


if __name__ == "__main__":
    main()
