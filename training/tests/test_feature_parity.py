"""Feature parity: the decoder's inputs at run time (src/rom/features.rs) are the ones it
was trained on (tacrom_rom/data.py).

`tacrom rom-features` (the Rust run-time code) solves fixed presses on a model's coarse
gel and writes, per press, the coarse lattice in gen-data's format, the exact float64
observation, the encoder input, the decoder query features at every lattice point and the
deformable region. Here the same presses go through the training code: `load_dir` (as
training reads gen-data's arrays), `encoder_input`, `QueryBuilder` and `region_mask` with
train.py's settings, and the results must agree. Two models: the shipped one (30 x 30 mm,
100 x 100 lattice) and a copy of its manifest for a 24 x 18 mm gel (80 x 60), so that a
mix-up of x and y, or of rows and columns, cannot hide behind a square lattice.

Tolerance. Training reads the observation as float32 metres and scales it in float32,
`f32(f32(x) * 1000)`; the run time scales the float64 value and rounds once,
`f32(x * 1000)`. Each rounding is within 2^-24 relative, so the two differ by at most
3 * 2^-24 relative (1.8e-7): FEATURE_RTOL = 2^-22 (2.4e-7). FEATURE_ATOL covers values so
small that float32 holds them as subnormals, where relative rounding bounds do not hold
(none occur in these presses). Positions and zeros (outside the gel, outside contact) are
computed with the same float64 operations on both sides and must be equal. Fed the exact
float64 observation, the training code must reproduce the run-time features bit for bit.
Any change of a definition (order, offset, stride, window, step, units, padding, position
normalisation, region rule) moves features by far more than this.
"""
import json
import os
import subprocess

import numpy as np
import pytest
import torch

from tacrom_rom import data as D
from tacrom_rom import train as T

ROOT = os.path.join(os.path.dirname(__file__), "..", "..")
TACROM = os.environ.get("TACROM_BIN", os.path.join(ROOT, "target", "release", "tacrom"))
SHIPPED = os.path.join(ROOT, "models", "rom-default")

FEATURE_RTOL = 2.0**-22
FEATURE_ATOL = float(np.finfo(np.float32).tiny) * 1000.0


def _non_square_model(path):
    """The shipped manifest for a 24 x 18 mm gel with the same 0.3 mm lattice pitch (no
    graphs: `rom-features` reads only the manifest)."""
    m = json.load(open(os.path.join(SHIPPED, "manifest.json")))
    size = [0.024, 0.018, m["gel"]["size"][2]]
    nx, ny = 80, 60
    spec = D.Spec(size=tuple(size), nx=nx, ny=ny)
    m["gel"]["size"] = size
    m["lattice"].update(size=size, nx=nx, ny=ny)
    m["encoder_input"] = spec.encoder_len
    m["files"]["encoder"]["inputs"]["observation"] = [1, spec.encoder_len]
    os.makedirs(path)
    json.dump(m, open(os.path.join(path, "manifest.json"), "w"), indent=1)
    return path


def _conditioned_model(path):
    """The shipped manifest of a model conditioned on the gel's material (two more encoder
    inputs and query features); the presses are solved on its default gel, which lies
    inside the ranges."""
    m = json.load(open(os.path.join(SHIPPED, "manifest.json")))
    m["conditioning"] = {"poisson": [0.3, 0.48], "friction": [0.0, 1.0]}
    spec = D.Spec(size=tuple(m["gel"]["size"]), nx=m["lattice"]["nx"], ny=m["lattice"]["ny"],
                  conditioning=m["conditioning"])
    m["encoder_input"], m["query_features"] = spec.encoder_len, spec.query_len
    m["files"]["encoder"]["inputs"]["observation"] = [1, spec.encoder_len]
    for key in ("decoder", "jacobian"):
        m["files"][key]["inputs"]["query"] = [-1, spec.query_len]
    if "pressure" in m["files"]:  # the decoder's query, then the load window
        m["files"]["pressure"]["inputs"]["query"] = [-1, spec.query_len + spec.patch**2]
    os.makedirs(path)
    json.dump(m, open(os.path.join(path, "manifest.json"), "w"), indent=1)
    return path


@pytest.fixture(scope="module", params=["shipped", "non-square", "conditioned"])
def rust(request, tmp_path_factory):
    """The run-time side: features.json, the samples as training loads them, and per press
    the arrays the Rust code computed."""
    if not os.path.isfile(TACROM):
        pytest.fail(f"{TACROM} is missing: `cargo build --release` (make test-train builds it)")
    root = tmp_path_factory.mktemp(f"rom-features-{request.param}")
    model = {"shipped": lambda p: SHIPPED, "non-square": _non_square_model,
             "conditioned": _conditioned_model}[request.param](str(root / "model"))
    out = root / "features"
    r = subprocess.run([TACROM, "rom-features", "--out", str(out), "--model", model],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    meta = json.load(open(out / "features.json"))
    spec, _, arrays, metas = D.load_dir(str(out), drop_unconverged=False)
    assert [m["index"] for m in metas] == [p["index"] for p in meta["presses"]]
    load = lambda what, i: np.load(out / f"{what}-{i:06d}.npy")  # noqa: E731
    presses = [{k: load(k, p["index"]) for k in ("observation", "encoder", "query", "region", "pressure", "load")}
               for p in meta["presses"]]
    return meta, spec, arrays, presses


def _close(py, rs, what):
    assert py.shape == rs.shape and py.dtype == rs.dtype == np.float32, (what, py.shape, rs.shape)
    err = np.abs(py.astype(np.float64) - rs.astype(np.float64))
    bound = FEATURE_ATOL + FEATURE_RTOL * np.abs(rs.astype(np.float64))
    bad = np.argwhere(err > bound)
    assert len(bad) == 0, (f"{what}: {len(bad)} of {err.size} features differ beyond float32 "
                           f"round-off, first at {bad[0].tolist()}: training {py[tuple(bad[0])]!r}, "
                           f"run time {rs[tuple(bad[0])]!r}; max difference {err.max():.3g}")
    return float((err / np.maximum(np.abs(rs), 1e-30)).max())


def _training_features(spec, lattice):
    """Encoder inputs [S, E], queries at every lattice point [S, ny*nx, F] from lattices
    [S, >=2, ny, nx] in model units, as train.py builds them."""
    lat = torch.from_numpy(lattice)
    enc = D.encoder_input(spec, lat)
    qb = D.QueryBuilder(spec)
    padded = qb.pad(lat)
    flat = torch.arange(spec.ny * spec.nx)
    rows, cols = flat // spec.nx, flat % spec.nx
    S = lat.shape[0]
    b = torch.arange(S)[:, None].expand(S, flat.numel())
    q = qb(padded, b, rows.expand(S, -1), cols.expand(S, -1))
    return enc.numpy(), q.numpy()


def test_the_lattice_and_region_settings_are_the_training_ones(rust):
    meta, spec, arrays, presses = rust
    # load_dir builds the spec from gen-data's size and lattice with data.py's defaults;
    # the run time takes the manifest's.
    assert spec.to_json() == meta["lattice"]
    assert (spec.encoder_len, spec.query_len) == (meta["encoder_len"], meta["query_len"])
    assert meta["region"] == {"eps_mm": T.REGION_EPS_MM, "grow": T.REGION_GROW}
    assert arrays.shape == (len(presses), 3 + spec.material_inputs, spec.ny, spec.nx)
    for p, a in zip(meta["presses"], arrays):
        # Real presses: contact, a deformed coarse gel, a region, the zero padding used.
        assert p["max_penetration"] > 3e-4 and p["max_coarse"] > 3e-4
        assert 0 < p["region_points"] < spec.nx * spec.ny
    assert (arrays[1, 1, :, 0] > 0).any() and (arrays[1, 1, 0, :] > 0).any(), \
        "the corner press should pierce the gel at its -x and +y edges"


def test_training_data_is_the_run_time_observation_in_float32(rust):
    meta, spec, arrays, presses = rust
    for a, p in zip(arrays, presses):
        obs32 = p["observation"].astype(np.float32)
        np.testing.assert_array_equal(a[:2], obs32 * np.float32(spec.depth_scale))


def test_encoder_input_parity(rust):
    meta, spec, arrays, presses = rust
    enc, _ = _training_features(spec, arrays)
    worst = max(_close(e, p["encoder"], f"encoder input of press {k}")
                for k, (e, p) in enumerate(zip(enc, presses)))
    print(f"encoder input: largest relative difference {worst:.3g} (tolerance {FEATURE_RTOL:.3g})")


def test_query_feature_parity(rust):
    meta, spec, arrays, presses = rust
    _, q = _training_features(spec, arrays)
    worst = 0.0
    for k, (qk, p) in enumerate(zip(q, presses)):
        rs = p["query"]
        # Positions: the same float64 expression on both sides, rounded once.
        np.testing.assert_array_equal(qk[:, :2], rs[:, :2], err_msg=f"positions of press {k}")
        # Zeros (outside the gel, outside contact) are exact on both sides.
        np.testing.assert_array_equal(qk == 0, rs == 0, err_msg=f"zero features of press {k}")
        worst = max(worst, _close(qk, rs, f"query features of press {k}"))
    print(f"query features: largest relative difference {worst:.3g} (tolerance {FEATURE_RTOL:.3g})")


def test_features_of_the_exact_observation_are_bit_identical(rust):
    """The only difference is the float32 storage of the training data: fed the float64
    observation, the training code computes the run time's float32 features exactly."""
    meta, spec, arrays, presses = rust
    exact = np.stack([p["observation"] for p in presses]) * spec.depth_scale
    # The reference channel (unused by the features) and the material channels as stored.
    exact = np.concatenate([exact, arrays[:, 2:].astype(np.float64)], axis=1)
    enc, q = _training_features(spec, exact)
    for k, p in enumerate(presses):
        np.testing.assert_array_equal(enc[k].astype(np.float32), p["encoder"])
        np.testing.assert_array_equal(q[k].astype(np.float32), p["query"])


def test_region_parity(rust):
    meta, spec, arrays, presses = rust
    region = D.region_mask(arrays, T.REGION_GROW, T.REGION_EPS_MM)
    for k, p in enumerate(presses):
        rs = p["region"].astype(bool)
        diff = np.argwhere(region[k] != rs)
        assert len(diff) == 0, (f"press {k}: the region differs at {len(diff)} points, first "
                                f"(row, col) {diff[0].tolist()}")


def test_pressure_head_load_window_parity(rust):
    """The pressure head's window of the coarse load (tacrom_rom.pressure.load_windows, from
    the load rounded to float32 as the training data stores it) is the run time's
    (features::load_window) bit for bit: both gather the same float32 values, with zeros
    outside the lattice; and it holds a load where the presses touch."""
    from tacrom_rom.pressure import load_windows

    meta, spec, arrays, presses = rust
    qb = D.QueryBuilder(spec)
    flat = torch.arange(spec.ny * spec.nx)
    rows, cols = flat // spec.nx, flat % spec.nx
    for k, p in enumerate(presses):
        load = torch.from_numpy(p["pressure"].astype(np.float32)[None])
        w = load_windows(qb, load, 0, rows, cols).numpy()
        np.testing.assert_array_equal(w, p["load"], err_msg=f"load window of press {k}")
        assert p["pressure"].max() > 0, f"press {k} carries no load"
