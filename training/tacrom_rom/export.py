"""ONNX export of a trained model: encoder, decoder, decoder Jacobian, and the manifest.

Opset pinned to OPSET; inputs and outputs are named (the Rust side checks them at load):

* encoder.onnx          observation [1, E] -> z [1, r]
* decoder.onnx          z [1, r], query [N, F] -> depth [N, 1]
* decoder_jacobian.onnx z [1, r], query [N, F] -> depth [N, 1], jacobian [N, r]

N is dynamic ("points"). Units: millimetres of depth (manifest `lattice.depth_scale`).
"""
from __future__ import annotations

import json
import os

import torch

from .model import DecoderJacobian

OPSET = 17
FORMAT = "tacrom-rom-1"
# Reduced energy (Eq. 4) weights, model units; see src/rom/mod.rs.
REFINEMENT = {
    "max_iterations": 10,
    "tolerance": 1e-5,
    "stride": 4,
    "contact_stride": 4,
    "w_inertia": 1.0,
    "w_elastic": 0.001,
    "w_contact": 0.1,
    "anchor": "encoder",
}


def _export(module, args, path, input_names, output_names, dynamic_axes):
    module.eval()
    torch.onnx.export(
        module,
        args,
        path,
        input_names=input_names,
        output_names=output_names,
        dynamic_axes=dynamic_axes,
        opset_version=OPSET,
        do_constant_folding=True,
        dynamo=False,
    )


# Loosest run-time tolerance of the coarse solve a model accepts (the sensor refuses a looser
# one): on the quick benchmark rom's depth error moved by 0.2 um between the training data's
# 1e-3 and 1e-2 (docs/configuration.md, "tolerance").
MAX_TOLERANCE = 1e-2


def recipe(dataset):
    """The coarse solve of the training data (the data set's own record, or, for data sets
    written before it had one, the solver of that time at its default tolerance 1e-3)."""
    r = dict(dataset.get("recipe") or {
        "dx": dataset.get("coarse_dx"),
        "material": "corotated",
        "solver": "relaxation",
        "tolerance": 1e-3,
    })
    r.setdefault("max_tolerance", MAX_TOLERANCE)
    return r


def decoder_hidden(model):
    """The decoder's hidden layer widths (the manifest's `decoder_hidden`)."""
    return [lin.out_features for lin in model.decoder.mlp.linears]


def export_model(model, spec, dataset, out, training=None, data=None, validation=None, refinement=True,
                 region_eps_mm=1e-3, region_grow=4):
    os.makedirs(out, exist_ok=True)
    r = model.decoder.latent
    z = torch.zeros(1, r)
    q = torch.zeros(7, spec.query_len)
    obs = torch.zeros(1, spec.encoder_len)
    with torch.no_grad():
        _export(model.encoder, (obs,), os.path.join(out, "encoder.onnx"), ["observation"], ["z"], None)
        _export(model.decoder, (z, q), os.path.join(out, "decoder.onnx"), ["z", "query"], ["depth"],
                {"query": {0: "points"}, "depth": {0: "points"}})
        _export(DecoderJacobian(model.decoder), (z, q), os.path.join(out, "decoder_jacobian.onnx"),
                ["z", "query"], ["depth", "jacobian"],
                {"query": {0: "points"}, "depth": {0: "points"}, "jacobian": {0: "points"}})
    E = spec.encoder_len
    F = spec.query_len
    manifest = {
        "format": FORMAT,
        "opset": OPSET,
        "gel": {
            "size": list(spec.size),
            "young": dataset.get("young"),
            "poisson": dataset.get("poisson"),
            "density": dataset.get("density"),
            "friction": dataset.get("friction"),
            "material": dataset.get("material", "fixed_corotated"),
        },
        "coarse_dx": dataset.get("coarse_dx"),
        "reference_dx": dataset.get("fine_dx"),
        "recipe": recipe(dataset),
        "lattice": spec.to_json(),
        "latent": r,
        "decoder_hidden": decoder_hidden(model),
        "encoder_input": E,
        "query_features": F,
        "coarse_feature": spec.coarse_index,
        "region": {"eps_mm": region_eps_mm, "grow": region_grow},
        "files": {
            "encoder": {"path": "encoder.onnx", "inputs": {"observation": [1, E]}, "outputs": {"z": [1, r]}},
            "decoder": {"path": "decoder.onnx", "inputs": {"z": [1, r], "query": [-1, F]},
                        "outputs": {"depth": [-1, 1]}},
            "jacobian": {"path": "decoder_jacobian.onnx", "inputs": {"z": [1, r], "query": [-1, F]},
                         "outputs": {"depth": [-1, 1], "jacobian": [-1, r]}},
        },
        "refinement": dict(REFINEMENT, enabled=bool(refinement)),
        **({"conditioning": spec.conditioning} if spec.conditioning else {}),
        "training": training or {},
        "data": data or {},
        "validation": validation or {},
    }
    with open(os.path.join(out, "manifest.json"), "w") as f:
        json.dump(manifest, f, indent=1)
    torch.save(model.state_dict(), os.path.join(out, "weights.pt"))
    return manifest
