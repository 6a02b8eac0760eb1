"""Train the reduced-order model on paired data and export it (manifest + ONNX).

    python -m tacrom_rom.train --data data/rom-v2 --out models/rom-default [--steps N]
        [--latent 64] [--no-multiscale] [--points 96] [--seed 0]

Losses (model units: millimetres of depth):
* reconstruction: mean squared error of the decoded depth against the reference (finer
  MPM) depth at query points drawn mostly from where the surface can deform;
* multi-scale supervision: the decoded depth differences between each query point and a
  neighbour k lattice steps away, k in {1, 2, 4} (detail at several scales), against the
  reference's (off with --no-multiscale);
* consistency with the coarse solver (weight 0.1): 0.4 |v_hat - v|^2 + 0.6 |F_hat - F|^2
  at the encoder's sub-lattice points of the deformable region, where v is the coarse
  surface's vertical displacement (its depth) and F its surface deformation gradient's
  out-of-plane row (the depth slopes along x and y, over one encoder stride); the hats
  are the decoder's.
Adam, lr 1e-4, betas (0.9, 0.999), batch 32 presses.
"""
from __future__ import annotations

import argparse
import glob
import json
import math
import os
import shlex
import sys
import time

import numpy as np
import torch

from . import data as D
from .export import export_model
from .model import HIDDEN, Autoencoder

CONSISTENCY_WEIGHT = 0.1
MULTISCALE_WEIGHT = 1.0
REGION_GROW = 4
REGION_EPS_MM = 1e-3


def augment(arrays):
    """The 8 symmetries of the square lattice (mirrors and quarter turns) of every sample:
    the gel, its grid and an isotropic material are symmetric under them, so each is
    another valid pair. [S, C, n, n] -> [8 S, C, n, n] (sample-major)."""
    if arrays.shape[-1] != arrays.shape[-2]:
        return arrays, 1
    out = []
    for a in arrays:
        for k in range(4):
            r = np.rot90(a, k, axes=(1, 2))
            out.append(r)
            out.append(r[:, :, ::-1])
    return np.ascontiguousarray(np.stack(out)), 8


def split(metas, held_out):
    val = np.array([m["family"] in held_out for m in metas])
    return np.where(~val)[0], np.where(val)[0]


class Batcher:
    def __init__(self, spec, arrays, rng, device="cpu"):
        self.spec = spec
        self.device = torch.device(device)
        self.arrays = torch.from_numpy(arrays).to(self.device)
        self.rng = rng
        self.qb = D.QueryBuilder(spec, self.device)
        self.region = D.region_mask(arrays, REGION_GROW, REGION_EPS_MM)
        self.region_idx = [np.flatnonzero(r) for r in self.region]
        s, o = spec.encoder_stride, spec.encoder_offset
        enc = np.zeros((spec.ny, spec.nx), bool)
        enc[o::s, o::s] = True
        # Encoder points whose +x and -y (row+s) neighbours exist.
        enc[:, spec.nx - s:] = False
        enc[spec.ny - s:, :] = False
        self.enc_idx = [np.flatnonzero(r & enc) for r in self.region]

    def draw(self, idx, n_points):
        """Random query points per sample: 80% in the region, 20% anywhere."""
        rows, cols = [], []
        nx, ny = self.spec.nx, self.spec.ny
        for i in idx:
            reg = self.region_idx[i]
            k_reg = int(0.8 * n_points) if len(reg) else 0
            a = reg[self.rng.integers(0, len(reg), k_reg)] if k_reg else np.zeros(0, int)
            b = self.rng.integers(0, nx * ny, n_points - k_reg)
            flat = np.concatenate([a, b])
            rows.append(flat // nx)
            cols.append(flat % nx)
        return self.to_device(rows), self.to_device(cols)

    def to_device(self, parts):
        return torch.from_numpy(np.stack(parts)).to(self.device)

    def draw_enc(self, idx, n_points):
        rows, cols = [], []
        nx = self.spec.nx
        for i in idx:
            e = self.enc_idx[i]
            if len(e) == 0:
                e = np.array([self.spec.encoder_offset * (nx + 1)])
            flat = e[self.rng.integers(0, len(e), n_points)]
            rows.append(flat // nx)
            cols.append(flat % nx)
        return self.to_device(rows), self.to_device(cols)


def losses(model, batcher, idx, n_points, multiscale, rng):
    spec = batcher.spec
    lat = batcher.arrays[torch.from_numpy(np.asarray(idx)).to(batcher.device)]  # [B, C, ny, nx]
    B = lat.shape[0]
    z = model.encoder(D.encoder_input(spec, lat))
    padded = batcher.qb.pad(lat)
    bidx = torch.arange(B, device=batcher.device)[:, None]
    rows, cols = batcher.draw(idx, n_points)
    bb = bidx.expand_as(rows)
    q = batcher.qb(padded, bb, rows, cols)
    pred = model.decoder.forward_batched(z, q)
    ref = lat[bb, 2, rows, cols]
    loss_rec = ((pred - ref) ** 2).mean()
    out = {"rec": loss_rec}
    total = loss_rec
    if multiscale:
        k = int(rng.choice([1, 2, 4]))
        along_x = torch.from_numpy(rng.random(tuple(rows.shape)) < 0.5).to(batcher.device)
        r2 = torch.where(along_x, rows, (rows + k).clamp(max=spec.ny - 1))
        c2 = torch.where(along_x, (cols + k).clamp(max=spec.nx - 1), cols)
        q2 = batcher.qb(padded, bb, r2, c2)
        pred2 = model.decoder.forward_batched(z, q2)
        ref2 = lat[bb, 2, r2, c2]
        loss_ms = (((pred2 - pred) - (ref2 - ref)) ** 2).mean() + ((pred2 - ref2) ** 2).mean()
        out["ms"] = loss_ms
        total = total + MULTISCALE_WEIGHT * loss_ms
    # Consistency with the coarse solver at encoder points.
    s = spec.encoder_stride
    er, ec = batcher.draw_enc(idx, 32)
    eb = bidx.expand_as(er)
    d0 = model.decoder.forward_batched(z, batcher.qb(padded, eb, er, ec))
    dx_ = model.decoder.forward_batched(z, batcher.qb(padded, eb, er, ec + s))
    dy_ = model.decoder.forward_batched(z, batcher.qb(padded, eb, er + s, ec))
    c0, cx, cy = lat[eb, 0, er, ec], lat[eb, 0, er, ec + s], lat[eb, 0, er + s, ec]
    h = spec.pitch * spec.depth_scale * s
    f_hat = torch.stack([(dx_ - d0) / h, (dy_ - d0) / h], -1)
    f = torch.stack([(cx - c0) / h, (cy - c0) / h], -1)
    loss_cons = 0.4 * ((d0 - c0) ** 2).mean() + 0.6 * ((f_hat - f) ** 2).sum(-1).mean()
    out["cons"] = loss_cons
    total = total + CONSISTENCY_WEIGHT * loss_cons
    out["total"] = total
    return out


@torch.no_grad()
def decode_lattice(model, spec, lat_np, chunk=8192):
    """Full decode (region only, coarse elsewhere) of samples [S, 3, ny, nx] -> [S, ny, nx],
    then the contact constraint max(d, p) and the clamp to [0, T], as in src/rom."""
    qb = D.QueryBuilder(spec)
    lat = torch.from_numpy(lat_np)
    z = model.encoder(D.encoder_input(spec, lat))
    region = D.region_mask(lat_np, REGION_GROW, REGION_EPS_MM)
    out = lat_np[:, 0].copy()
    padded = qb.pad(lat)
    for s in range(lat.shape[0]):
        flat = np.flatnonzero(region[s])
        for a in range(0, len(flat), chunk):
            f = torch.from_numpy(flat[a : a + chunk])
            rows, cols = f // spec.nx, f % spec.nx
            q = qb(padded, torch.full_like(rows, s), rows, cols)
            out[s].reshape(-1)[flat[a : a + chunk]] = model.decoder(z[s : s + 1], q)[:, 0].numpy()
    t_mm = spec.size[2] * spec.depth_scale
    return np.clip(np.maximum(out, lat_np[:, 1]), 0.0, t_mm)


def fov_crop(spec, a, fov=(0.024, 0.018)):
    """The central image field of view (the sensor's default) of [..., ny, nx] arrays."""
    cx = int(round(fov[0] / spec.pitch))
    cy = int(round(fov[1] / spec.pitch))
    x0 = (spec.nx - cx) // 2
    y0 = (spec.ny - cy) // 2
    return a[..., y0 : y0 + cy, x0 : x0 + cx]


def scored(spec, a, meta):
    """The part of a pair's [..., ny, nx] arrays that is scored: the sensor's default field of
    view on the model's own gel, the whole window for a press of the gel family (`gen-data
    --gel-family`: its contact may lie anywhere in the window, as `tacrom eval-rom` scores it)."""
    return a if meta.get("gel") else fov_crop(spec, a)


def metrics(model, spec, arrays, metas, idx):
    """Depth MAE (mm) per method over the held-out presses `idx`, the mean of each press's
    MAE over its scored region, and per family."""
    if len(idx) == 0:
        return {}
    lat = arrays[idx]
    rom = decode_lattice(model, spec, lat)
    ref, coarse, pen = lat[:, 2], lat[:, 0], lat[:, 1]
    per = lambda a: np.array([np.abs(scored(spec, a[k] - ref[k], metas[i])).mean()  # noqa: E731
                              for k, i in enumerate(idx)])
    err = {"coarse": per(coarse), "rom": per(rom), "rigid": per(pen)}
    per_family = {}
    for fam in sorted({metas[i]["family"] for i in idx}):
        sel = [k for k, i in enumerate(idx) if metas[i]["family"] == fam]
        per_family[fam] = {
            "samples": len(sel),
            "mae_coarse_mm": float(err["coarse"][sel].mean()),
            "mae_rom_mm": float(err["rom"][sel].mean()),
        }
    return {
        "samples": int(len(idx)),
        "mae_coarse_mm": float(err["coarse"].mean()),
        "mae_rom_no_refinement_mm": float(err["rom"].mean()),
        "mae_rigid_mm": float(err["rigid"].mean()),
        "per_family": per_family,
    }


def sample_indices(path):
    """Sorted indices of the samples written to a data directory."""
    return sorted(int(f[7:13]) for f in os.listdir(path) if f.startswith("sample-") and f.endswith(".json"))


# Coarse depth error (mm, over the field of view) below which a held-out press says nothing
# about a model: the 0.7 mm reference itself is 1.4 um from the 0.3 mm fine mode.
VALIDATION_MIN_COARSE_MAE_MM = 5e-4


def write_validation_pairs(out, spec, arrays, metas, va, per_family, first=0):
    """Held-out pairs for the Rust test, stratified by family (it gates each family and the
    pool): up to `per_family` of each held-out family, the finest references first, among the
    presses whose coarse depth is at least VALIDATION_MIN_COARSE_MAE_MM off the reference
    (chosen by the data, not by the model). Files are numbered from `first`; returns the
    number written."""
    vdir = os.path.join(out, "validation")
    os.makedirs(vdir, exist_ok=True)
    picks = []
    for family in sorted({metas[i]["family"] for i in va}):
        members = [i for i in va if metas[i]["family"] == family]
        informative = [i for i in members if np.abs(scored(spec, arrays[i][0] - arrays[i][2], metas[i])).mean()
                       >= VALIDATION_MIN_COARSE_MAE_MM]
        members = sorted(informative or members, key=lambda i: metas[i].get("reference_dx") or 1.0)
        picks += members[:per_family]
    for k, i in enumerate(picks, start=first):
        np.save(os.path.join(vdir, f"pair-{k}.npy"), (arrays[i][:3] / spec.depth_scale).astype(np.float32))
        with open(os.path.join(vdir, f"pair-{k}.json"), "w") as f:
            json.dump(metas[i], f)
    return len(picks)


def validation_sets(model, spec, paths, out, per_family, conditioning):
    """The held-out presses of the data sets `paths` (each a validation set of one gel:
    `tacrom gen-data --gel-family --gel-size ... --held-out-only`) as the model's
    `validation/` pairs, `per_family` of each family from each set, replacing the pairs of
    its own held-out presses; returns their metrics per set for the manifest."""
    vdir = os.path.join(out, "validation")
    for f in glob.glob(os.path.join(vdir, "pair-*")):
        os.remove(f)
    report, written = {}, 0
    for path in paths:
        spec2, ds2, arrays2, metas2 = D.load_dir(path, conditioned=conditioning is not None,
                                                 conditioning=conditioning)
        if (spec2.size, spec2.nx, spec2.ny) != (spec.size, spec.nx, spec.ny):
            raise SystemExit(f"{path}: lattice {spec2.nx} x {spec2.ny} over {spec2.size}, the model's is "
                             f"{spec.nx} x {spec.ny} over {spec.size}")
        idx = np.array([i for i, m in enumerate(metas2) if m.get("held_out")], dtype=int)
        if len(idx) == 0:
            raise SystemExit(f"{path}: no held-out presses")
        n = write_validation_pairs(out, spec, arrays2, metas2, list(idx), per_family, first=written)
        written += n
        gel = (ds2.get("gel_family") or {}).get("gel") or ds2.get("size")
        report[path] = dict(metrics(model, spec, arrays2, metas2, idx), gel=gel, pairs=n,
                            command=gen_command(path, ds2))
        print(f"validation set {path} (gel {gel}): {n} pairs; {json.dumps(report[path])}", flush=True)
    return report


def gen_command(path, ds):
    """The `tacrom gen-data` command that regenerates the data set in `path` (for a merged
    one, the merge of the data sets it came from)."""
    if ds.get("merged_from"):
        return f"python -m tacrom_rom.merge {path} " + " ".join(ds["merged_from"]) + \
            " (each written by tacrom gen-data)"
    n = max(sample_indices(path), default=-1) + 1
    mm = lambda key: f"{1e3 * ds.get(key):g}"  # noqa: E731  (the data set's metres, the CLI's mm)
    solver = (ds.get("recipe") or {}).get("solver", "relaxation")
    return (f"tacrom gen-data --out {path} --samples {n} --seed {ds.get('seed')} "
            f"--coarse-dx {mm('coarse_dx')} --fine-dx {mm('fine_dx')} --pitch {mm('pitch')} "
            + (f"--coarse-solver {solver} " if solver != "relaxation" else "")
            + ("--gel-family " if ds.get("gel_family") else "")
            + "".join(f"--gel-size {','.join(f'{1e3 * v:g}' for v in gel)} --held-out-only "
                      for gel in [(ds.get("gel_family") or {}).get("gel")] if gel)
            + "".join(f"--{name} {lo:g},{hi:g} " for name in ("poisson", "friction")
                      for lo, hi in [ds.get(f"{name}_range") or (None, None)] if lo is not None)
            + f"--fine-max-iterations {ds.get('fine_max_iterations')} [--shard K/N for parallel shards]")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True, help="paired data set (tacrom gen-data) to train on")
    p.add_argument("--out", required=True, help="model directory to write (manifest, ONNX files, weights)")
    p.add_argument("--reference", default=None,
                   help="data set of the same presses with a finer reference (gen-data --fine-dx): "
                        "its reference replaces --data's wherever it holds the sample")
    p.add_argument("--steps", type=int, default=2000, help="optimizer steps")
    p.add_argument("--latent", type=int, default=64, help="size of the latent code")
    p.add_argument("--decoder-hidden", default=",".join(map(str, HIDDEN)),
                   help="the decoder's hidden layer widths (the paper's %(default)s; narrower costs less "
                        "per decoded point at run time)")
    p.add_argument("--encoder-from", default=None, metavar="MODEL_DIR",
                   help="take the encoder of this model directory (its weights.pt) and train the decoder "
                        "alone on its latent codes (a decoder of other widths for the same encoder)")
    p.add_argument("--points", type=int, default=96, help="query points per press per step")
    p.add_argument("--batch", type=int, default=32, help="presses per step")
    p.add_argument("--lr", type=float, default=1e-4, help="Adam learning rate")
    p.add_argument("--lr-schedule", choices=("constant", "cosine"), default="constant",
                   help="the learning rate over the steps: constant, or cosine decay from --lr to zero at "
                        "--steps (the last weights then do not sit wherever the last noisy steps left them)")
    p.add_argument("--no-multiscale", action="store_true", help="no multi-scale supervision loss")
    p.add_argument("--no-refinement", action="store_true", help="ablation 'w/o physics': manifest disables latent refinement")
    p.add_argument("--seed", type=int, default=0, help="seed of the weights, the batches and the query points")
    inputs = p.add_mutually_exclusive_group()
    inputs.add_argument("--no-conditioning", action="store_true",
                        help="a data set of several materials without the material inputs: the model "
                        "reads the gel's material from the coarse channel alone")
    inputs.add_argument("--poisson-only", action="store_true",
                        help="condition on Poisson's ratio alone (the friction input held at 0; the "
                        "manifest's `materials` then states the friction it serves)")
    p.add_argument("--no-augment", action="store_true", help="no mirror / quarter-turn augmentation")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    p.add_argument("--device", default="cpu", help="torch device of the training loop (cpu, cuda); "
                   "the model is evaluated and exported on the CPU")
    p.add_argument("--region-eps-mm", type=float, default=REGION_EPS_MM,
                   help="coarse depth above which the manifest's deformable region starts at run time "
                        "(training uses 1e-3 mm; the linear gel's slow fall-off wants 0.01)")
    p.add_argument("--region-grow", type=int, default=REGION_GROW,
                   help="lattice steps the manifest's deformable region is grown by at run time (training "
                        "samples the region grown by %(default)s; rom-linear decodes 2, as accurate on the full "
                        "profile at 15 %% less decoder time: docs/rom.md)")
    p.add_argument("--also", action="append", default=[], metavar="DATA",
                   help="another paired data set of the same lattice and coarse solve trained on beside "
                        "--data (repeatable): its materials are read in --data's ranges, its held-out "
                        "families are validation too (a family data set beside the default gel's)")
    p.add_argument("--max-seconds", type=float, default=None, help="stop training after this wall time")
    p.add_argument("--validation-per-family", type=int, default=2,
                   help="held-out pairs of each held-out family copied into the model for tests")
    p.add_argument("--validation", action="append", default=[], metavar="DATA",
                   help="a validation set of one gel (gen-data --gel-family --gel-size ... --held-out-only; "
                        "repeatable): the model's validation pairs come from these sets' held-out presses "
                        "instead of its own, and the manifest gets their metrics")
    a = p.parse_args(argv)

    torch.set_num_threads(a.threads)
    torch.manual_seed(a.seed)
    rng = np.random.default_rng(a.seed)
    spec, ds, arrays, metas = D.load_dir(
        a.data, conditioned="poisson" if a.poisson_only else not a.no_conditioning)
    held_out = set(ds["held_out"])
    also = []
    for path in a.also:
        spec2, ds2, arrays2, metas2 = D.load_dir(
            path, conditioned="poisson" if a.poisson_only else not a.no_conditioning,
            conditioning=spec.conditioning)
        for key in ("size", "lattice", "pitch", "recipe"):
            if ds2.get(key) != ds.get(key):
                raise SystemExit(f"{path}: dataset.json {key} = {ds2.get(key)!r}, {a.data} has {ds.get(key)!r}")
        if spec.conditioning:
            for name, (lo, hi) in spec.conditioning.items():
                for m in metas2:
                    v = m.get(name, ds2[name])
                    if not lo <= v <= hi:
                        raise SystemExit(f"{path}: sample {m['index']}'s {name} {v} lies outside "
                                         f"{a.data}'s range [{lo}, {hi}]")
        for m in metas2:
            m["data"] = path
        held_out |= set(ds2["held_out"])
        arrays = np.concatenate([arrays, arrays2])
        metas = metas + metas2
        also.append({"path": path, "pairs": len(metas2), "command": gen_command(path, ds2)})
        print(f"{len(metas2)} pairs from {path} beside {a.data}", flush=True)
    tr, va = split(metas, held_out)
    references = None
    if a.reference:
        fine_ds, n_fine = D.overlay_references(a.reference, spec, ds, arrays, metas)
        count = lambda ids, dx: sum(1 for i in ids if metas[i]["reference_dx"] == dx)
        references = {"path": a.reference, "replaced": n_fine,
                      "indices": sorted(m["index"] for m in metas if m["reference_dx"] == fine_ds["fine_dx"]),
                      "train": {str(dx): count(tr, dx) for dx in (fine_ds["fine_dx"], ds["fine_dx"])},
                      "validation": {str(dx): count(va, dx) for dx in (fine_ds["fine_dx"], ds["fine_dx"])}}
        print(f"references from {a.reference} ({fine_ds['fine_dx']} m) for {n_fine} pairs: "
              f"train {references['train']}, validation {references['validation']}", flush=True)
        references["command"] = gen_command(a.reference, fine_ds)
    if len(tr) == 0:
        tr = np.arange(len(metas))
    print(f"{len(metas)} pairs: {len(tr)} train, {len(va)} held-out validation", flush=True)
    hidden = tuple(int(w) for w in a.decoder_hidden.split(","))
    model = Autoencoder(spec.encoder_len, spec.query_len, spec.coarse_index, a.latent, hidden)
    trained = model.parameters()
    if a.encoder_from:
        state = torch.load(os.path.join(a.encoder_from, "weights.pt"), weights_only=True)
        model.encoder.load_state_dict({k[len("encoder."):]: v for k, v in state.items() if k.startswith("encoder.")})
        model.encoder.requires_grad_(False)
        trained = model.decoder.parameters()
    opt = torch.optim.Adam(trained, lr=a.lr, betas=(0.9, 0.999))
    if a.no_augment:
        train_arrays, n_aug = arrays, 1
    else:
        train_arrays, n_aug = augment(arrays)
    tr_aug = (tr[:, None] * n_aug + np.arange(n_aug)[None, :]).reshape(-1)
    model.to(a.device)
    batcher = Batcher(spec, train_arrays, rng, a.device)
    t0 = time.time()
    step = 0
    for step in range(1, a.steps + 1):
        if a.lr_schedule == "cosine":
            for group in opt.param_groups:
                group["lr"] = a.lr * 0.5 * (1.0 + math.cos(math.pi * (step - 1) / a.steps))
        idx = rng.choice(tr_aug, size=min(a.batch, len(tr_aug)), replace=len(tr_aug) < a.batch)
        out = losses(model, batcher, idx, a.points, not a.no_multiscale, rng)
        opt.zero_grad()
        out["total"].backward()
        opt.step()
        if step % 100 == 0 or step == 1:
            parts = " ".join(f"{k} {v.item():.3e}" for k, v in out.items())
            print(f"step {step} {parts} ({time.time() - t0:.0f}s)", flush=True)
        if a.max_seconds and time.time() - t0 > a.max_seconds:
            break
    seconds = time.time() - t0
    model.cpu()
    model.eval()
    os.makedirs(a.out, exist_ok=True)
    torch.save(model.state_dict(), os.path.join(a.out, "weights.pt"))
    val = metrics(model, spec, arrays, metas, va)
    train_m = metrics(model, spec, arrays, metas, tr[: min(len(tr), 64)])
    print("validation", json.dumps(val, indent=1), flush=True)
    os.makedirs(a.out, exist_ok=True)
    training = {
        "command": "python -m tacrom_rom.train " + " ".join(shlex.quote(x) for x in (argv if argv is not None else sys.argv[1:])),
        "steps": step,
        "seconds": round(seconds, 1),
        "threads": a.threads,
        "device": a.device,
        "batch": a.batch,
        "points_per_press": a.points,
        "augmentation": "none" if a.no_augment else "8 lattice symmetries",
        "optimizer": {"name": "adam", "lr": a.lr, "betas": [0.9, 0.999], "schedule": a.lr_schedule},
        "losses": {"reconstruction": 1.0, "multiscale": 0.0 if a.no_multiscale else MULTISCALE_WEIGHT,
                   "consistency": CONSISTENCY_WEIGHT, "consistency_v": 0.4, "consistency_F": 0.6},
        "torch": torch.__version__,
    }
    indices = sorted(m["index"] for m in metas if "data" not in m)
    all_idx = sample_indices(a.data)
    n_gen = (max(all_idx) + 1) if all_idx else 0
    regenerate = gen_command(a.data, ds)
    data_info = {"command": regenerate, "generated": len(all_idx),
                 "contiguous": all_idx == list(range(n_gen)),
                 "dropped_unconverged_reference": len(all_idx) - len(indices),
                 "path": a.data, "pairs": len(metas), "train": int(len(tr)), "validation": int(len(va)),
                 "families_train": sorted({metas[i]["family"] for i in tr}),
                 "families_validation": sorted({metas[i]["family"] for i in va}), "dataset": ds}
    if references:
        data_info["references"] = references
    if also:
        data_info["also"] = also
    model_ds = dict(ds, fine_dx=fine_ds["fine_dx"]) if references else ds
    validation = {"held_out": val, "train_subset": train_m}
    if a.validation:
        validation["gels"] = validation_sets(model, spec, a.validation, a.out, a.validation_per_family,
                                             spec.conditioning)
    export_model(model, spec, model_ds, a.out, training=training, data=data_info,
                 validation=validation,
                 refinement=not a.no_refinement, region_eps_mm=a.region_eps_mm,
                 region_grow=a.region_grow)
    if not a.validation:
        write_validation_pairs(a.out, spec, arrays, metas, va, a.validation_per_family)
    print(f"wrote {a.out} in {seconds:.0f}s of training", flush=True)


if __name__ == "__main__":
    main()
