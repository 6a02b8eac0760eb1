"""Training side: a tiny train-and-export run on synthetic pairs, ONNX Runtime parity
with PyTorch (max error < 1e-4), and the exported Jacobian against autograd."""
import json
import os

import numpy as np
import onnxruntime as ort
import pytest
import torch

from tacrom_rom import data as D
from tacrom_rom import train as T
from tacrom_rom.model import Autoencoder, DecoderJacobian, hidden_of
from tacrom_rom.train import main as train_main

PARITY_TOL = 1e-4


def write_synthetic(path, n=12, nx=40, ny=40, seed=0):
    """Pairs in gen-data's format: a smooth bowl (coarse), a sharper one (reference)."""
    os.makedirs(path, exist_ok=True)
    rng = np.random.default_rng(seed)
    ds = {"size": [0.012, 0.012, 0.004], "young": 1.19e5, "poisson": 0.43, "density": 1050.0,
          "friction": 0.5, "material": "fixed_corotated", "coarse_dx": 1.4e-3, "fine_dx": 7e-4,
          "pitch": 3e-4, "lattice": [ny, nx], "samples": n, "seed": seed,
          "held_out": ["ridges"]}
    with open(os.path.join(path, "dataset.json"), "w") as f:
        json.dump(ds, f)
    y, x = np.mgrid[0:ny, 0:nx].astype(np.float32)
    for i in range(n):
        cx, cy, r, d = rng.uniform(10, 30), rng.uniform(10, 30), rng.uniform(3, 8), rng.uniform(2e-4, 8e-4)
        rr = np.hypot(x - cx, y - cy) / r
        pen = np.clip(d - d * rr**2, 0, None)
        fine = np.maximum(pen, d * np.exp(-rr**2))
        coarse = np.maximum(pen, 0.8 * d * np.exp(-0.7 * rr**2))
        np.save(os.path.join(path, f"sample-{i:06d}.npy"), np.stack([coarse, pen, fine]).astype(np.float32))
        fam = "ridges" if i % 4 == 0 else "sphere"
        with open(os.path.join(path, f"sample-{i:06d}.json"), "w") as f:
            json.dump({"index": i, "family": fam, "reference": {"converged": True}}, f)


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    root = tmp_path_factory.mktemp("rom")
    data = root / "data"
    out = root / "model"
    write_synthetic(str(data))
    train_main(["--data", str(data), "--out", str(out), "--steps", "3", "--batch", "4",
                "--points", "16", "--latent", "16", "--validation-per-family", "2"])
    return out


def test_tiny_train_and_export_writes_a_complete_model(tiny_model):
    m = json.load(open(tiny_model / "manifest.json"))
    for f in m["files"].values():
        assert (tiny_model / f["path"]).is_file()
    assert m["latent"] == 16
    assert "mae_coarse_mm" in m["validation"]["held_out"]
    assert (tiny_model / "validation" / "pair-0.npy").is_file()


def _sessions(model_dir):
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    return {k: ort.InferenceSession(str(model_dir / v), opts, providers=["CPUExecutionProvider"])
            for k, v in [("enc", "encoder.onnx"), ("dec", "decoder.onnx"), ("jac", "decoder_jacobian.onnx")]}


def _load_torch(model_dir):
    m = json.load(open(model_dir / "manifest.json"))
    L = m["lattice"]
    spec = D.Spec(size=tuple(L["size"]), nx=L["nx"], ny=L["ny"])
    model = Autoencoder(spec.encoder_len, spec.query_len, spec.coarse_index, m["latent"], hidden_of(m))
    model.load_state_dict(torch.load(model_dir / "weights.pt"))
    model.eval()
    return spec, model


def test_onnx_parity_with_pytorch(tiny_model):
    spec, model = _load_torch(tiny_model)
    s = _sessions(tiny_model)
    g = torch.Generator().manual_seed(1)
    obs = torch.rand(1, spec.encoder_len, generator=g)
    q = torch.rand(300, spec.query_len, generator=g)
    with torch.no_grad():
        z = model.encoder(obs)
        d = model.decoder(z, q)
        d2, jac = DecoderJacobian(model.decoder)(z, q)
    z_ort = s["enc"].run(["z"], {"observation": obs.numpy()})[0]
    d_ort = s["dec"].run(["depth"], {"z": z.numpy(), "query": q.numpy()})[0]
    dj, jac_ort = s["jac"].run(["depth", "jacobian"], {"z": z.numpy(), "query": q.numpy()})
    errs = [np.abs(z_ort - z.numpy()).max(), np.abs(d_ort - d.numpy()).max(),
            np.abs(dj - d2.numpy()).max(), np.abs(jac_ort - jac.numpy()).max()]
    print("parity max errors (z, depth, jacobian depth, jacobian):", errs)
    assert max(errs) < PARITY_TOL, errs


def test_exported_jacobian_is_the_exact_gradient(tiny_model):
    spec, model = _load_torch(tiny_model)
    g = torch.Generator().manual_seed(2)
    z = torch.randn(1, model.decoder.latent, generator=g, dtype=torch.float64)
    q = torch.rand(20, spec.query_len, generator=g, dtype=torch.float64)
    dec = model.decoder.double()
    _, jac = DecoderJacobian(dec)(z, q)
    auto = torch.autograd.functional.jacobian(lambda zz: dec(zz, q)[:, 0], z)[:, 0, :]
    assert torch.allclose(jac, auto, atol=1e-9, rtol=1e-7), (jac - auto).abs().max()


def test_a_narrower_decoder_keeps_the_encoder_it_is_trained_on(tiny_model, tmp_path):
    """`--encoder-from` with `--decoder-hidden`: the encoder's weights and graph come out
    unchanged, the decoder at the widths asked for, its graphs equal to PyTorch."""
    out = tmp_path / "narrow"
    data = tmp_path / "data"
    write_synthetic(str(data))
    train_main(["--data", str(data), "--out", str(out), "--steps", "5", "--batch", "4", "--points", "16",
                "--latent", "16", "--encoder-from", str(tiny_model), "--decoder-hidden", "8,4,2"])
    m = json.load(open(out / "manifest.json"))
    assert m["decoder_hidden"] == [8, 4, 2]
    assert json.load(open(tiny_model / "manifest.json"))["decoder_hidden"] == [512, 256, 128]
    wide = torch.load(tiny_model / "weights.pt")
    narrow = torch.load(out / "weights.pt")
    enc = [k for k in wide if k.startswith("encoder.")]
    assert enc and all(torch.equal(wide[k], narrow[k]) for k in enc)
    assert (out / "encoder.onnx").read_bytes() == (tiny_model / "encoder.onnx").read_bytes()
    assert narrow["decoder.mlp.linears.2.weight"].shape == (2, 4)
    spec, model = _load_torch(out)
    s = _sessions(out)
    g = torch.Generator().manual_seed(4)
    z = torch.randn(1, 16, generator=g)
    q = torch.rand(50, spec.query_len, generator=g)
    with torch.no_grad():
        d = model.decoder(z, q)
        _, jac = DecoderJacobian(model.decoder)(z, q)
    d_ort = s["dec"].run(["depth"], {"z": z.numpy(), "query": q.numpy()})[0]
    _, jac_ort = s["jac"].run(["depth", "jacobian"], {"z": z.numpy(), "query": q.numpy()})
    assert max(np.abs(d_ort - d.numpy()).max(), np.abs(jac_ort - jac.numpy()).max()) < PARITY_TOL


SHIPPED = os.path.join(os.path.dirname(__file__), "..", "..", "models", "rom-default")


@pytest.mark.skipif(not os.path.exists(os.path.join(SHIPPED, "weights.pt")), reason="no shipped model")
def test_shipped_model_onnx_parity_with_pytorch():
    import pathlib
    d = pathlib.Path(SHIPPED)
    spec, model = _load_torch(d)
    s = _sessions(d)
    g = torch.Generator().manual_seed(3)
    obs = torch.rand(1, spec.encoder_len, generator=g) * 0.5
    q = torch.rand(2000, spec.query_len, generator=g) * 0.5
    with torch.no_grad():
        z = model.encoder(obs)
        d_t = model.decoder(z, q)
        _, jac = DecoderJacobian(model.decoder)(z, q)
    z_ort = s["enc"].run(["z"], {"observation": obs.numpy()})[0]
    d_ort = s["dec"].run(["depth"], {"z": z.numpy(), "query": q.numpy()})[0]
    _, jac_ort = s["jac"].run(["depth", "jacobian"], {"z": z.numpy(), "query": q.numpy()})
    errs = [np.abs(z_ort - z.numpy()).max(), np.abs(d_ort - d_t.numpy()).max(), np.abs(jac_ort - jac.numpy()).max()]
    print("shipped model parity max errors (z, depth, jacobian):", errs)
    assert max(errs) < PARITY_TOL, errs


def _finer_copy(base, path, indices, ds_changes=None):
    """A data set of `base`'s presses with a different reference for `indices` only."""
    import shutil
    os.makedirs(path, exist_ok=True)
    ds = json.load(open(os.path.join(base, "dataset.json")))
    ds.update({"fine_dx": 3e-4}, **(ds_changes or {}))
    json.dump(ds, open(os.path.join(path, "dataset.json"), "w"))
    for i in indices:
        a = np.load(os.path.join(base, f"sample-{i:06d}.npy"))
        a[2] = a[2] * 1.5
        np.save(os.path.join(path, f"sample-{i:06d}.npy"), a)
        shutil.copy(os.path.join(base, f"sample-{i:06d}.json"), path)


def test_finer_references_replace_the_base_ones_where_present(tmp_path):
    base = tmp_path / "base"
    write_synthetic(str(base))
    finer = tmp_path / "finer"
    _finer_copy(str(base), str(finer), [0, 1, 2, 5])  # 0 is held out (ridges), 1, 2, 5 train
    spec, ds, arrays, metas = D.load_dir(str(base))
    before = arrays.copy()
    fine_ds, replaced = D.overlay_references(str(finer), spec, ds, arrays, metas)
    assert replaced == 4 and fine_ds["fine_dx"] == 3e-4
    for k, m in enumerate(metas):
        if m["index"] in (0, 1, 2, 5):
            np.testing.assert_allclose(arrays[k, 2], 1.5 * before[k, 2], rtol=1e-5, atol=1e-12)  # float32 roundings, denormals
            assert m["reference_dx"] == 3e-4
        else:
            np.testing.assert_array_equal(arrays[k, 2], before[k, 2])
            assert m["reference_dx"] == 7e-4
        np.testing.assert_array_equal(arrays[k, :2], before[k, :2])
    out = tmp_path / "model"
    train_main(["--data", str(base), "--reference", str(finer), "--out", str(out), "--steps", "2",
                "--batch", "4", "--points", "16", "--latent", "16", "--validation-per-family", "1"])
    m = json.load(open(out / "manifest.json"))
    assert m["reference_dx"] == 3e-4
    refs = m["data"]["references"]
    assert refs["replaced"] == 4 and refs["indices"] == [0, 1, 2, 5]
    assert refs["train"] == {"0.0003": 3, "0.0007": 6}
    assert refs["validation"] == {"0.0003": 1, "0.0007": 2}
    # The commands in millimetres, as the CLI reads them.
    assert "--fine-dx 0.7 " in m["data"]["command"] and "--fine-dx 0.3 " in refs["command"]


def test_finer_references_of_other_presses_are_refused(tmp_path):
    base = tmp_path / "base"
    write_synthetic(str(base))
    other = tmp_path / "other"
    _finer_copy(str(base), str(other), [3])
    a = np.load(other / "sample-000003.npy")
    a[0] += 1e-4
    np.save(other / "sample-000003.npy", a)
    spec, ds, arrays, metas = D.load_dir(str(base))
    with pytest.raises(SystemExit, match="sample-000003.npy: coarse channel differs"):
        D.overlay_references(str(other), spec, ds, arrays, metas)
    seeded = tmp_path / "seeded"
    _finer_copy(str(base), str(seeded), [3], {"seed": 7})
    with pytest.raises(SystemExit, match="seed = 7"):
        D.overlay_references(str(seeded), spec, ds, arrays, metas)


def test_force_factor_per_poisson_bin_of_a_ranged_data_set(tmp_path):
    """For presses whose Poisson's ratio is drawn from a range, the factor gets a table: per
    bin, the median ratio at the median Poisson's ratio (here ratio = 1 + nu exactly, so
    each entry lies on that line); held-out families and light presses are left out."""
    from tacrom_rom import force_factor as FF

    path = tmp_path / "ranged"
    os.makedirs(path)
    with open(path / "dataset.json", "w") as f:
        json.dump({"poisson": 0.3, "friction": 0.0, "poisson_range": [0.3, 0.48], "held_out": ["ridges"],
                   "fine_dx": 7e-4}, f)
    rng = np.random.default_rng(0)
    for i in range(400):
        nu = float(rng.uniform(0.3, 0.48))
        coarse = np.zeros((3, 4, 4), np.float32)
        coarse[0] = 1e-4  # coarse volume 16e-4, reference volume 8e-4 -> ratio = (fr / fc) * 2
        coarse[2] = 0.5e-4
        fc = 0.1
        fr = fc * (1 + nu) / 2
        family = "ridges" if i % 10 == 0 else "sphere"
        if i % 10 == 1:
            fc = fr = 1e-4  # below MIN_FORCE
        np.save(path / f"sample-{i:06d}.npy", coarse)
        with open(path / f"sample-{i:06d}.json", "w") as f:
            json.dump({"index": i, "family": family, "poisson": nu, "friction": 0.5,
                       "coarse": {"force": [0, 0, fc]}, "reference": {"converged": True, "force": [0, 0, fr]}}, f)
    k, n, _, _, _, table = FF.factor(str(path))
    assert n == 320
    assert len(table) == FF.POISSON_BINS
    nus = [nu for nu, _ in table]
    assert nus == sorted(nus) and 0.3 < nus[0] < nus[-1] < 0.48
    for nu, v in table:
        assert abs(v - (1 + nu)) < 2e-4, (nu, v)
    assert abs(k - (1 + np.median(nus))) < 0.02
    # A data set of one Poisson's ratio gets no table.
    assert FF.by_poisson(np.full(50, 0.43), np.ones(50), None) is None


@pytest.mark.parametrize("flag, conditioning", [
    ([], {"poisson": [0.3, 0.48], "friction": [0.0, 1.0]}),
    (["--poisson-only"], {"poisson": [0.3, 0.48], "friction": [0.5, 0.5]}),
    (["--no-conditioning"], None),
])
def test_material_inputs_of_a_ranged_data_set(tmp_path, flag, conditioning):
    """A data set of drawn materials trains a model with both material inputs, with
    Poisson's ratio's alone (the friction range collapsed to its midpoint: input 0), or
    with none; the manifest says which, and the input sizes follow."""
    data = tmp_path / "data"
    write_synthetic(str(data))
    ds = json.load(open(data / "dataset.json"))
    ds.update(poisson_range=[0.3, 0.48], friction_range=[0.0, 1.0], friction=0.0)
    json.dump(ds, open(data / "dataset.json", "w"))
    rng = np.random.default_rng(1)
    for js in data.glob("sample-*.json"):
        meta = json.load(open(js))
        meta.update(poisson=float(rng.uniform(0.3, 0.48)), friction=float(rng.uniform(0, 1)))
        json.dump(meta, open(js, "w"))
    spec, _, arrays, _ = D.load_dir(str(data), conditioned="poisson" if flag == ["--poisson-only"] else flag == [])
    out = tmp_path / "model"
    train_main(["--data", str(data), "--out", str(out), "--steps", "2", "--batch", "4", "--points", "16",
                "--latent", "16", "--validation-per-family", "1"] + flag)
    m = json.load(open(out / "manifest.json"))
    assert m.get("conditioning") == conditioning
    extra = 2 if conditioning else 0
    assert arrays.shape[1] == 3 + extra
    if flag == ["--poisson-only"]:
        assert np.all(arrays[:, 4] == 0) and np.ptp(arrays[:, 3]) > 0
    r, c = spec.encoder_dims()
    assert m["encoder_input"] == 2 * r * c + extra


def test_pressure_head_trains_exports_and_matches_onnx(tiny_model, tmp_path):
    """The pressure head (tacrom_rom.pressure) on synthetic pressure companions: it joins a
    copy of the model with `files.pressure` and a `pressure` record, and its ONNX graph
    follows PyTorch."""
    from tacrom_rom.pressure import PressureHead, main as pressure_main

    data = tmp_path / "data"
    write_synthetic(str(data))
    for npy in data.glob("sample-??????.npy"):
        a = np.load(npy)
        # A Hertz-like pressure where the reference presses (Pa); the coarse one smeared.
        p = 2e4 * np.sqrt(np.clip(a[1] / max(a[1].max(), 1e-12), 0, None))
        np.save(str(npy)[:-4] + "-pressure.npy", np.stack([0.8 * p, p]).astype(np.float32))
        js = str(npy)[:-4] + ".json"
        meta = json.load(open(js))
        fz = float(p.sum()) * 3e-4**2
        meta["coarse"] = {"force": [0.0, 0.0, 0.8 * fz]}
        meta["reference"]["force"] = [0.0, 0.0, fz]
        json.dump(meta, open(js, "w"))
    with open(data / "dataset.json") as f:
        ds = json.load(f)
    m0 = json.load(open(tiny_model / "manifest.json"))
    ds.update(recipe=m0["recipe"], coarse_dx=m0["coarse_dx"], size=m0["lattice"]["size"])
    with open(data / "dataset.json", "w") as f:
        json.dump(ds, f)
    out = tmp_path / "model"
    pressure_main(["--data", str(data), "--model", str(tiny_model), "--out", str(out),
                   "--steps", "3", "--batch", "2"])
    m = json.load(open(out / "manifest.json"))
    assert m["files"]["pressure"]["outputs"] == {"pressure": [-1, 1]}
    assert m["pressure"]["units"] == "coarse_force"
    assert "held_out" in m["pressure"]["validation"]
    assert "pressure" not in json.load(open(tiny_model / "manifest.json"))["files"]
    F = m["query_features"] + m["lattice"]["patch"] ** 2
    head = PressureHead(m["latent"], F)
    head.load_state_dict(torch.load(out / "pressure.pt"))
    head.eval()
    g = torch.Generator().manual_seed(4)
    z = torch.randn(1, m["latent"], generator=g)
    q = torch.rand(300, F, generator=g)
    with torch.no_grad():
        ref = head(z, q).numpy()
        batched = head.forward_batched(z, q[None])[0].numpy()
    sess = ort.InferenceSession(str(out / "pressure.onnx"), providers=["CPUExecutionProvider"])
    got = sess.run(["pressure"], {"z": z.numpy(), "query": q.numpy()})[0]
    assert np.abs(got - ref).max() < PARITY_TOL
    assert np.abs(batched - ref[:, 0]).max() < 1e-6


def test_small_presses_are_those_of_few_penetrated_lattice_points(tmp_path):
    from tacrom_rom.small import small_presses
    for index, count in [(0, 0), (3, 1), (7, 43), (8, 44), (12, 5)]:
        a = np.zeros((3, 10, 10), np.float32)
        a[1].flat[:count] = 1e-5
        a[1].flat[count:count + 3] = -1e-5  # lattice points clear of the indenter
        np.save(tmp_path / f"sample-{index:06d}.npy", a)
        (tmp_path / f"sample-{index:06d}.json").write_text("{}")
    np.save(tmp_path / "sample-000009-pressure.npy", np.ones((10, 10), np.float32))
    assert small_presses(str(tmp_path)) == [3, 7, 12]
    assert small_presses(str(tmp_path), 2, 44) == [7, 8, 12]


def test_force_factor_from_the_decoded_volumes(tmp_path):
    """With the model's decoded volumes (eval-rom's forces.csv), the factor is the median of
    F_ref / (F_coarse V_dec / V_coarse): here the decoder restores (1 + nu) times the
    reference's volume, so the volume factor from the references' is (1 + nu) times the one
    that makes the reported force the reference's; presses of another method, outside the
    sensor's volume ratio or not in the file are left out."""
    from tacrom_rom import force_factor as FF

    path = tmp_path / "ranged"
    os.makedirs(path)
    with open(path / "dataset.json", "w") as f:
        json.dump({"poisson": 0.3, "friction": 0.0, "poisson_range": [0.3, 0.48], "held_out": [],
                   "fine_dx": 7e-4}, f)
    rng = np.random.default_rng(1)
    rows = []
    for i in range(300):
        nu = float(rng.uniform(0.3, 0.48))
        a = np.zeros((3, 4, 4), np.float32)
        a[0], a[2] = 1e-4, 0.5e-4  # coarse volume 16e-4, reference 8e-4
        vc, vr = 16e-4, 8e-4
        vd = vr * (1 + nu)
        fc, fr = 0.1, 0.06
        np.save(path / f"sample-{i:06d}.npy", a)
        with open(path / f"sample-{i:06d}.json", "w") as f:
            json.dump({"index": i, "family": "sphere", "poisson": nu, "friction": 0.5,
                       "coarse": {"force": [0, 0, fc]}, "reference": {"converged": True, "force": [0, 0, fr]}}, f)
        if i % 50 == 7:
            continue  # not in the file
        if i % 50 == 9:
            vd = 5.0 * vc  # beyond the sensor's volume ratio
        rows.append(("model", f"sample-{i:06d}.npy", vc, vd, vr))
        rows.append(("other", f"sample-{i:06d}.npy", vc, 2 * vd, vr))
    csv_path = tmp_path / "forces.csv"
    with open(csv_path, "w") as f:
        f.write("method,sample,family,force_reference_n,force_reported_n,volume_coarse_m,volume_decoded_m,volume_reference_m\n")
        for m, s, vc, vd, vr in rows:
            f.write(f"{m},{s},sphere,0.06,0.06,{vc},{vd},{vr}\n")
    decoded = FF.decoded_volumes(str(csv_path), str(tmp_path / "model"))
    k, n, _, _, _, table = FF.factor(str(path), decoded)
    assert n == 300 - 6 - 6
    for nu, v in table:
        assert abs(v - 0.06 / (0.1 * 0.5 * (1 + nu))) < 2e-3, (nu, v)
    k_ref, *_ = FF.factor(str(path))
    assert abs(k_ref - 0.06 / (0.1 * 0.5)) < 1e-9
    with pytest.raises(SystemExit, match="no rows of method 'absent'"):
        FF.decoded_volumes(str(csv_path), str(tmp_path / "absent"))


def test_a_data_set_trained_beside_another(tmp_path):
    """`train --also`: the second data set's pairs join the first's, its materials read in
    the first's ranges (a fixed material of 0.43 and 0.5 maps to the inputs the first set's
    ranges give it), its held-out families are validation too; a data set of another
    lattice, or with a material outside the first's ranges, is refused naming the folder."""
    ranged, fixed = tmp_path / "ranged", tmp_path / "fixed"
    write_synthetic(str(ranged), n=8, seed=2)
    write_synthetic(str(fixed), n=8, seed=3)
    ds = json.load(open(ranged / "dataset.json"))
    ds.update(poisson_range=[0.3, 0.49], friction_range=[0.0, 1.0])
    json.dump(ds, open(ranged / "dataset.json", "w"))
    for js in ranged.glob("sample-*.json"):
        meta = json.load(open(js))
        meta.update(poisson=0.35, friction=0.2)
        json.dump(meta, open(js, "w"))
    spec, _, _, _ = D.load_dir(str(ranged))
    _, _, arrays, _ = D.load_dir(str(fixed), conditioning=spec.conditioning)
    assert np.allclose(arrays[:, 3:5, 0, 0], spec.material(0.43, 0.5))
    out = tmp_path / "model"
    train_main(["--data", str(ranged), "--also", str(fixed), "--out", str(out), "--steps", "2",
                "--batch", "4", "--points", "16", "--latent", "16", "--validation-per-family", "1"])
    m = json.load(open(out / "manifest.json"))
    assert m["conditioning"] == {"poisson": [0.3, 0.49], "friction": [0.0, 1.0]}
    assert m["data"]["also"][0]["pairs"] == 8 and m["data"]["pairs"] == 16
    other = tmp_path / "other"
    write_synthetic(str(other), n=4, nx=30, ny=30)
    with pytest.raises(SystemExit, match="other.*lattice"):
        train_main(["--data", str(ranged), "--also", str(other), "--out", str(tmp_path / "m2"), "--steps", "1"])
    ds = json.load(open(fixed / "dataset.json"))
    ds.update(poisson=0.495)
    json.dump(ds, open(fixed / "dataset.json", "w"))
    with pytest.raises(SystemExit, match="fixed.*poisson 0.495"):
        train_main(["--data", str(ranged), "--also", str(fixed), "--out", str(tmp_path / "m3"), "--steps", "1"])


def test_validation_pairs_from_sets_of_one_gel(tmp_path):
    """`train --validation`: the model's validation pairs are the held-out presses of the
    named sets (each a set of one gel), `--validation-per-family` of each family from each,
    numbered on across the sets, with their own reference spacing; the manifest records each
    set's metrics, its gel and the command that regenerates it. A family press is scored
    over its whole window, a press of the model's own gel over the field of view."""
    train, thin, thick = tmp_path / "train", tmp_path / "thin", tmp_path / "thick"
    write_synthetic(str(train), n=8, seed=1)
    for path, seed, gel in ((thin, 4, [0.018, 0.014, 0.0015]), (thick, 5, [0.04, 0.03, 0.006])):
        write_synthetic(str(path), n=8, seed=seed)
        ds = json.load(open(path / "dataset.json"))
        ds.update(fine_dx=0.0005, gel_family={"gel": gel})
        json.dump(ds, open(path / "dataset.json", "w"))
        for js in path.glob("sample-*.json"):
            meta = json.load(open(js))
            meta.update(gel={"size": gel}, held_out=meta["family"] == "ridges")
            json.dump(meta, open(js, "w"))
    out = tmp_path / "model"
    train_main(["--data", str(train), "--validation", str(thin), "--validation", str(thick), "--out", str(out),
                "--steps", "2", "--batch", "4", "--points", "16", "--latent", "16",
                "--validation-per-family", "1"])
    m = json.load(open(out / "manifest.json"))
    gels = m["validation"]["gels"]
    assert [gels[str(p)]["gel"] for p in (thin, thick)] == [[0.018, 0.014, 0.0015], [0.04, 0.03, 0.006]]
    pairs = sorted((out / "validation").glob("pair-*.json"))
    written = sum(gels[str(p)]["pairs"] for p in (thin, thick))
    assert len(pairs) == written > 0
    assert {f"pair-{k}.json" for k in range(written)} == {p.name for p in pairs}
    held_out = {p: [json.load(open(js)) for js in sorted(p.glob("sample-*.json"))] for p in (thin, thick)}
    for p, metas in held_out.items():
        families = {x["family"] for x in metas if x["held_out"]}
        assert gels[str(p)]["pairs"] == len(families)
        assert gels[str(p)]["samples"] == sum(x["held_out"] for x in metas)
        assert gels[str(p)]["command"].startswith(f"tacrom gen-data --out {p} ")
        gel = json.load(open(p / "dataset.json"))["gel_family"]["gel"]
        assert f"--gel-family --gel-size {','.join(f'{1e3 * v:g}' for v in gel)} --held-out-only " in \
            gels[str(p)]["command"]
    for js in pairs:
        meta = json.load(open(js))
        assert meta["held_out"] and meta["reference_dx"] == 0.0005 and "gel" in meta
    # A family press's MAE is its whole window's; the model's own gel's, the field of view's.
    spec, _, arrays, metas = D.load_dir(str(thin))
    a = arrays[0, 0] - arrays[0, 2]
    assert T.scored(spec, a, metas[0]).shape == a.shape
    assert T.scored(spec, a, {}).shape == T.fov_crop(spec, a).shape != a.shape
    # The same pairs attached to a trained model afterwards (`tacrom_rom.validate`).
    from tacrom_rom.validate import main as validate_main
    plain = tmp_path / "plain"
    train_main(["--data", str(train), "--out", str(plain), "--steps", "2", "--batch", "4", "--points", "16",
                "--latent", "16"])
    validate_main([str(plain), str(thin), str(thick)])
    again = json.load(open(plain / "manifest.json"))["validation"]["gels"]
    assert [again[str(p)]["pairs"] for p in (thin, thick)] == [gels[str(p)]["pairs"] for p in (thin, thick)]
    assert sorted(x.name for x in (plain / "validation").glob("pair-*")) == sorted(
        x.name for x in (out / "validation").glob("pair-*"))


def test_cosine_schedule_decays_the_learning_rate_to_zero(tmp_path, monkeypatch):
    """`--lr-schedule cosine`: the Adam learning rate of step k of n is lr (1 + cos(pi (k-1)
    / n)) / 2, from --lr at the first step towards zero at the last; the manifest records
    it."""
    data = tmp_path / "data"
    write_synthetic(str(data), n=8, seed=6)
    seen = []
    step = torch.optim.Adam.step

    def record(self, *args, **kwargs):
        seen.append(self.param_groups[0]["lr"])
        return step(self, *args, **kwargs)

    monkeypatch.setattr(torch.optim.Adam, "step", record)
    out = tmp_path / "model"
    train_main(["--data", str(data), "--out", str(out), "--steps", "4", "--batch", "4", "--points", "16",
                "--latent", "16", "--lr", "1e-3", "--lr-schedule", "cosine"])
    want = [1e-3 * 0.5 * (1 + np.cos(np.pi * k / 4)) for k in range(4)]
    assert np.allclose(seen, want, rtol=1e-12)
    assert json.load(open(out / "manifest.json"))["training"]["optimizer"]["schedule"] == "cosine"
