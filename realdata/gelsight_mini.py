"""Real GelSight Mini ball presses as a `tacrom calibrate` folder: the 24 presses of a
4 mm ball and the untouched gel that Taxim ships as its GelSight Mini calibration
(taxim 1.4.1 on PyPI, MIT licence: taxim/calib/gelsight_mini/dataPack.npz).

    python realdata/gelsight_mini.py prepare OUT   # background.png, press_NNN.png, presses.json, LICENSE-taxim
    python realdata/gelsight_mini.py check OUT     # the annotated centres against the images

`prepare` downloads the wheel into target/real/cache (once; its sha256 is pinned below)
and writes the images as 8-bit RGB PNGs in the camera's orientation (the pack stores them
BGR; only the channel order changes), so `tacrom calibrate OUT --mirror` reads them in the
sensor's orientation. Rerunning it with every output present does nothing. Standard
library and numpy only; `read_png` and `write_png` serve realdata/taxim_render.py too.
"""

import argparse
import hashlib
import io
import json
import os
import pathlib
import struct
import subprocess
import sys
import zipfile
import zlib

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
CACHE = ROOT / "target" / "real" / "cache"

TAXIM_VERSION = "1.4.1"
WHEEL = f"taxim-{TAXIM_VERSION}-py3-none-any.whl"
WHEEL_SHA256 = "dba5b71468631781ed9e9339bcb3f7a6cd8e070402b3664320ec9f19b26a06f3"
DATA_PACK = "taxim/calib/gelsight_mini/dataPack.npz"
LICENSE = f"taxim-{TAXIM_VERSION}.dist-info/licenses/LICENSE"

# The indenter: a ball of 4 mm diameter; the pixel size is params.json's `sensor.pixmm`
# beside the data pack.
BALL_RADIUS_MM = 2.0
PIXEL_SIZE_MM = 0.0295

# The pack's `touch_center` is [column, row]. Checked (`check`) against the centroid of
# each press's difference from the background (|press - background| summed over the
# channels, above 30 grey levels): read as [column, row], the annotations lie 2 to 25 px
# from the centroids (median 8 px; columns within 11 px, rows up to 24 px off), inside the
# pressed region; read as [row, column] they lie 127 to 180 px away, outside it. The
# centroids themselves cluster at two spots, (342, 217) for presses 0-12 and (335, 232)
# for 13-23, so the scatter is that of the annotations, not of the presses: their circles
# are placed by hand, and the worst (presses 4, 15, 17) sit 18 to 24 px below the visible
# contact. They are written as given (whole pixels; `center_px` has `c` at the centre of
# column `c`).
CENTRE_THRESHOLD = 30


def write_png(path: pathlib.Path, rgb: np.ndarray) -> None:
    """Writes an (H, W, 3) uint8 array as an 8-bit RGB PNG (no filter), atomically."""
    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    h, w, c = rgb.shape
    if c != 3:
        raise ValueError(f"{path}: expected 3 channels, got {c}")
    raw = np.concatenate([np.zeros((h, 1), np.uint8), rgb.reshape(h, w * 3)], axis=1)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    png = (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(raw.tobytes(), 6))
        + chunk(b"IEND", b"")
    )
    write_atomic(path, png)


def read_png(path: pathlib.Path) -> np.ndarray:
    """Reads an 8-bit RGB PNG (any filter, not interlaced) as an (H, W, 3) uint8 array."""
    data = pathlib.Path(path).read_bytes()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG")
    pos, idat, header = 8, [], None
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos : pos + 4])
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + n]
        pos += 12 + n
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
    if header is None:
        raise ValueError(f"{path}: no IHDR")
    w, h, depth, colour, _, _, interlace = header
    if (depth, colour, interlace) != (8, 2, 0):
        raise ValueError(f"{path}: only 8-bit RGB, not interlaced, is read (depth {depth}, colour type {colour})")
    raw = np.frombuffer(zlib.decompress(b"".join(idat)), np.uint8).reshape(h, 1 + w * 3)
    out = np.zeros((h, w * 3), np.uint8)
    prev = np.zeros(w * 3, np.int32)
    for r in range(h):
        f, line = raw[r, 0], raw[r, 1:].astype(np.int32)
        if f == 0:
            cur = line
        elif f == 1:  # Sub: a running sum per channel
            cur = np.cumsum(line.reshape(w, 3), axis=0).reshape(-1) % 256
        elif f == 2:  # Up
            cur = (line + prev) % 256
        elif f in (3, 4):  # Average, Paeth: sequential along the row
            cur = np.zeros(w * 3, np.int32)
            for i in range(w * 3):
                a = cur[i - 3] if i >= 3 else 0
                b = prev[i]
                if f == 3:
                    pred = (a + b) // 2
                else:
                    cc = prev[i - 3] if i >= 3 else 0
                    p = a + b - cc
                    pa, pb, pc = abs(p - a), abs(p - b), abs(p - cc)
                    pred = a if pa <= pb and pa <= pc else (b if pb <= pc else cc)
                cur[i] = (line[i] + pred) % 256
        else:
            raise ValueError(f"{path}: unknown filter {f} on row {r}")
        out[r] = cur
        prev = cur
    return out.reshape(h, w, 3)


def write_atomic(path: pathlib.Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp.{os.getpid()}")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def sha256(path: pathlib.Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def wheel() -> pathlib.Path:
    """The taxim wheel in the cache, downloaded when absent and checked against its pin."""
    path = CACHE / WHEEL
    if not path.exists():
        CACHE.mkdir(parents=True, exist_ok=True)
        subprocess.run(
            [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:",
             f"taxim=={TAXIM_VERSION}", "-d", str(CACHE)],
            check=True,
        )
    digest = sha256(path)
    if digest != WHEEL_SHA256:
        raise SystemExit(f"{path}: sha256 {digest}, expected {WHEEL_SHA256}; delete it to download it again")
    return path


def outputs(n: int) -> list[str]:
    return ["background.png"] + [press_name(i) for i in range(n)] + ["LICENSE-taxim", "presses.json"]


def press_name(i: int) -> str:
    return f"press_{i:03d}.png"


def prepare(out: pathlib.Path) -> None:
    listing = out / "presses.json"
    if listing.exists():
        n = len(json.loads(listing.read_text())["presses"])
        if all((out / name).exists() for name in outputs(n)):
            print(f"{out}: up to date ({n} presses)")
            return
    with zipfile.ZipFile(wheel()) as z:
        pack = np.load(io.BytesIO(z.read(DATA_PACK)))
        licence = z.read(LICENSE).decode()
        background, imgs = pack["f0"], pack["imgs"]
        centres, radii = pack["touch_center"], pack["touch_radius"]
    out.mkdir(parents=True, exist_ok=True)
    # BGR -> RGB; the camera's orientation is kept (`tacrom calibrate --mirror`).
    write_png(out / "background.png", background[..., ::-1])
    presses = []
    for i, img in enumerate(imgs):
        write_png(out / press_name(i), img[..., ::-1])
        column, row = (float(v) for v in centres[i])
        presses.append({
            "image": press_name(i),
            "ball_radius_mm": BALL_RADIUS_MM,
            "pixel_size_mm": PIXEL_SIZE_MM,
            "center_px": [column, row],
            "contact_radius_px": float(radii[i]),
        })
    write_atomic(
        out / "LICENSE-taxim",
        (f"The images in this folder come from taxim {TAXIM_VERSION} (https://pypi.org/project/taxim/), "
         f"{DATA_PACK}, under its licence:\n\n{licence}").encode(),
    )
    # Written last: its presence with every image marks a complete folder.
    body = {"background": "background.png", "presses": presses}
    write_atomic(listing, (json.dumps(body, indent=1) + "\n").encode())
    print(f"{out}: {len(presses)} presses, {imgs.shape[2]} x {imgs.shape[1]} px")


def check(out: pathlib.Path) -> None:
    """Prints, per press, the centroid of its difference from the background and its
    distance from the annotated centre read either way round."""
    listing = json.loads((out / "presses.json").read_text())
    background = read_png(out / listing["background"]).astype(np.int32)
    print(f"{'press':>5} {'centroid (col, row)':>20} {'centre (col, row)':>18} {'offset':>14} {'dist':>6}"
          f" {'as (row, col)':>13}")
    dists = []
    for i, p in enumerate(listing["presses"]):
        diff = np.abs(read_png(out / p["image"]).astype(np.int32) - background).sum(-1)
        rows, cols = np.nonzero(diff > CENTRE_THRESHOLD)
        cc, cr = cols.mean(), rows.mean()
        c, r = p["center_px"]
        dist, swapped = np.hypot(c - cc, r - cr), np.hypot(r - cc, c - cr)
        dists.append(dist)
        print(f"{i:>5} {cc:>10.1f} {cr:>9.1f} {c:>9.0f} {r:>8.0f} {c - cc:>+7.1f} {r - cr:>+6.1f}"
              f" {dist:>6.1f} {swapped:>13.1f}")
    print(f"distance from the centroid, as [column, row]: median {np.median(dists):.1f} px, max {max(dists):.1f} px")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("command", choices=["prepare", "check"])
    ap.add_argument("out", type=pathlib.Path)
    args = ap.parse_args()
    {"prepare": prepare, "check": check}[args.command](args.out)


if __name__ == "__main__":
    main()
