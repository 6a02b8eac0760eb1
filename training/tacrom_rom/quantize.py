"""An 8-bit decoder for a reduced-order model's dense decoding (manifest `files.decoder`).

    python -m tacrom_rom.quantize MODEL_DIR

The decoder runs on every lattice point of the deformable region (800 to 1,300 at 320 x
240 under a 5 mm sphere), about 190,000 multiply-adds each, most of them in the two hidden
layers 512 -> 256 -> 128. ONNX Runtime's dynamic quantization turns those two products into
8-bit integer ones (weights per tensor, fixed in the file; activations per call, from
their own range): about twice as fast on a CPU core, where the float product already runs
near its peak. The first layer (the query's 52 features and the latent) and the output
stay in float: they carry the inputs' and the depth's full range.

Writes MODEL_DIR/decoder_int8.onnx from MODEL_DIR/decoder.onnx and points the manifest's
`files.decoder` at it (same inputs and outputs), recording what was quantized under
`files.decoder.quantized`. `decoder.onnx` stays beside it: the float original this file is
made from. The latent refinement keeps the float Jacobian graph.
"""
from __future__ import annotations

import argparse
import json
import os

import onnx
from onnxruntime.quantization import QuantType, quantize_dynamic

SOURCE = "decoder.onnx"
TARGET = "decoder_int8.onnx"
# The hidden layers' products, as the exported graph names them.
HIDDEN = ("/linears.1/Gemm", "/linears.2/Gemm")


def hidden_nodes(model):
    """The names of the hidden layers' nodes, checked to be in the graph."""
    names = {n.name for n in model.graph.node}
    missing = [n for n in HIDDEN if n not in names]
    if missing:
        raise SystemExit(f"{SOURCE}: no node {missing}; the decoder's layout changed")
    return [n.name for n in model.graph.node if n.name not in HIDDEN and n.op_type in ("MatMul", "Gemm")]


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model_dir", metavar="MODEL_DIR", help="model directory holding the float decoder and manifest.json")
    a = p.parse_args(argv)
    model_dir = a.model_dir
    src = os.path.join(model_dir, SOURCE)
    dst = os.path.join(model_dir, TARGET)
    keep = hidden_nodes(onnx.load(src))
    # The quantizer rewrites each Gemm into a MatMul and an Add first, and names the
    # MatMul after it: the float layers are excluded under both names.
    exclude = keep + [f"{n}_MatMul" for n in keep]
    quantize_dynamic(src, dst, weight_type=QuantType.QInt8, per_channel=False, nodes_to_exclude=exclude)
    quantized = [n.name for n in onnx.load(dst).graph.node if n.op_type == "MatMulInteger"]
    if len(quantized) != len(HIDDEN):
        raise SystemExit(f"{dst}: {len(quantized)} integer products, expected {len(HIDDEN)}")
    path = os.path.join(model_dir, "manifest.json")
    with open(path) as f:
        m = json.load(f)
    dec = m["files"]["decoder"]
    dec["path"] = TARGET
    dec["quantized"] = {
        "from": SOURCE,
        "layers": list(HIDDEN),
        "weights": "int8, per tensor",
        "activations": "uint8, dynamic per call",
        "command": f"python -m tacrom_rom.quantize {model_dir}",
    }
    with open(path, "w") as f:
        json.dump(m, f, indent=1)
    print(f"{dst}: hidden layers {', '.join(HIDDEN)} in 8 bits; manifest points at it")


if __name__ == "__main__":
    main()
