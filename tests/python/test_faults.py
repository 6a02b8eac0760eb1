"""Faults from outside the plugin, through the real `mujoco` package: a model file
truncated under a running sensor, a gel cache folder that cannot be written, is full or
holds garbage, ONNX Runtime failing every call of a coupled sensor's decoder."""

import copy
import shutil

import mujoco
import numpy as np
import pytest

from conftest import ROOT, evaluate, with_config


def test_a_model_file_truncated_under_a_running_sensor(press_xml, tmp_path):
    """Catches: a sensor that rereads its ONNX files per frame (it would fail or return
    garbage once they are cut), and a load that crashes on them. The running sensor keeps
    its loaded graphs and goes on pressing deeper; a new MjData of the same model, and so a
    copy of the data, is refused with an error naming the sensor, the attribute, the
    value and the file; the running sensor is untouched by that refusal."""
    model_dir = tmp_path / "rom"
    shutil.copytree(ROOT / "models" / "rom-default", model_dir)
    xml = with_config(press_xml, physics="rom", model=str(model_dir), outputs="depth force",
                      resolution="64 48")
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    before = evaluate(m, d, 0.3e-3)
    for name in ("encoder.onnx", "decoder.onnx"):
        with open(model_dir / name, "r+b") as f:
            f.truncate(100)
    after = evaluate(m, d, 0.4e-3)
    assert np.isfinite(after["depth"]).all() and np.isfinite(after["force"]).all()
    assert after["depth"].max() > before["depth"].max() > 0
    assert after["force"][2] > before["force"][2] > 0
    for make in (lambda: mujoco.MjData(m), lambda: copy.copy(d)):
        with pytest.raises(Exception) as err:
            make()
        text = str(err.value)
        assert "'touch'" in text and "attribute 'model'" in text, text
        assert str(model_dir) in text and "encoder.onnx" in text, text
    again = evaluate(m, d, 0.45e-3)
    assert np.isfinite(again["depth"]).all()
    assert again["force"][2] > after["force"][2]


# A small gel on the linear solver, whose compliance the gel cache keeps: pressed in a
# fresh process with the cache folder set by the environment; prints the force.
CACHE_PROBE = """
import sys
sys.path.insert(0, {tests!r})
import mujoco, numpy as np
import tacrom
from conftest import evaluate, with_config
xml = with_config(open({press!r}).read(), physics="coarse", solver="linear",
                  size="0.012 0.012 0.003", dx="0.001", outputs="depth force",
                  resolution="32 32")
m = mujoco.MjModel.from_xml_string(xml)
out = evaluate(m, mujoco.MjData(m), 0.3e-3)
assert np.isfinite(out["depth"]).all()
print(repr(float(out["force"][2])))
"""


def test_a_cache_folder_that_cannot_be_written_or_holds_nothing_costs_no_sensor(tmp_path):
    """Catches: a load that fails or crashes where the gel cache cannot be used. The same
    small linear gel pressed in fresh processes with the cache folder (``$TACROM_CACHE``)
    somewhere it cannot be made (under a regular file), capped at 0 MiB (full: every file
    it writes is evicted), corrupt (every cache file overwritten with garbage) and usable:
    each gives the same force to the last bit (the compliance is computed, or read back
    bit for bit, whatever the folder allows)."""
    import os
    import subprocess
    import sys

    script = CACHE_PROBE.format(tests=str(ROOT / "tests" / "python"),
                                press=str(ROOT / "examples" / "press.xml"))
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    usable = tmp_path / "cache"

    def force(**env):
        run = subprocess.run([sys.executable, "-c", script], env={**os.environ, **env},
                             capture_output=True, text=True, timeout=600)
        assert run.returncode == 0, run.stderr
        return float(run.stdout.strip().splitlines()[-1])

    fresh = force(TACROM_CACHE=str(usable))
    assert fresh > 0
    assert any(usable.iterdir()), "the usable cache holds the compliance"
    assert force(TACROM_CACHE=str(usable)) == fresh
    for f in usable.iterdir():
        f.write_bytes(b"garbage" * 100)
    assert force(TACROM_CACHE=str(usable)) == fresh
    assert force(TACROM_CACHE=str(blocker / "cache")) == fresh
    assert force(TACROM_CACHE=str(tmp_path / "full"), TACROM_CACHE_MB="0") == fresh


# A mesh pressed 0.3 mm into the linear gel in a fresh process, the cache folder set by
# the environment; prints a digest of the sensor data and the force.
MESH_PROBE = """
import hashlib, sys
sys.path.insert(0, {tests!r})
import mujoco, numpy as np
import tacrom
from conftest import with_config
xml = with_config(open({press!r}).read(), physics="coarse", solver="linear",
                  outputs="depth force", resolution="32 24")
xml = xml.replace('type="sphere" size="0.005"', 'type="mesh" mesh="hexagon"')
xml = xml.replace("<worldbody>", '<asset><mesh name="hexagon" file="{mesh}" '
                  'scale="0.001 0.001 0.001"/></asset><worldbody>', 1)
m = mujoco.MjModel.from_xml_string(xml)
d = mujoco.MjData(m)
mujoco.mj_forward(m, d)
g = m.geom("ball").id
mesh = m.geom_dataid[g]
v = m.mesh_vert[m.mesh_vertadr[mesh] : m.mesh_vertadr[mesh] + m.mesh_vertnum[mesh]]
lowest = (d.geom_xpos[g] + v @ d.geom_xmat[g].reshape(3, 3).T)[:, 2].min()
d.qpos[0] = lowest + 0.3e-3
mujoco.mj_forward(m, d)
out = tacrom.outputs(m, d, "touch")
data = np.concatenate([out["depth"].ravel(), out["force"]])
print(hashlib.sha256(data.tobytes()).hexdigest(), repr(float(out["force"][2])))
"""


def test_a_meshs_distance_grid_is_kept_for_the_next_process_and_a_cut_one_rebuilt(tmp_path):
    """Catches: a mesh's distance grid that the gel cache's folder does not keep, one read
    back that is not the built one, one written again by every process, or a cut file
    used. The hexagon mesh pressed into the linear gel in fresh processes: the first
    builds the grid and leaves one ``mesh-*.bin`` file; the next reads it (the file is not
    written again) and gives the same sensor data to the last bit; a file cut in half is
    rebuilt and rewritten whole, the same data again; with the cache off, the same data."""
    import os
    import subprocess
    import sys

    script = MESH_PROBE.format(tests=str(ROOT / "tests" / "python"),
                               press=str(ROOT / "examples" / "press.xml"),
                               mesh=str(ROOT / "examples" / "meshes" / "hexagon.stl"))
    cache = tmp_path / "cache"

    def press(**env):
        run = subprocess.run([sys.executable, "-c", script], env={**os.environ, **env},
                             capture_output=True, text=True, timeout=600)
        assert run.returncode == 0, run.stderr
        digest, force = run.stdout.strip().splitlines()[-1].split()
        assert float(force) > 0.05, force
        return digest

    first = press(TACROM_CACHE=str(cache))
    grids = sorted(cache.glob("mesh-*.bin"))
    assert len(grids) == 1, sorted(p.name for p in cache.iterdir())
    kept, stamp = grids[0].read_bytes(), grids[0].stat().st_mtime_ns
    assert press(TACROM_CACHE=str(cache)) == first
    assert grids[0].stat().st_mtime_ns == stamp, "a kept grid was written again"
    grids[0].write_bytes(kept[: len(kept) // 2])
    assert press(TACROM_CACHE=str(cache)) == first
    assert grids[0].read_bytes() == kept, "the cut file was not rebuilt whole"
    assert press(TACROM_CACHE="off") == first


def _varint(v: int) -> bytes:
    out = bytearray()
    while True:
        byte, v = v & 0x7F, v >> 7
        if v == 0:
            out.append(byte)
            return bytes(out)
        out.append(byte | 0x80)


def _field(number: int, value) -> bytes:
    """One protobuf field: an int (varint), or bytes / str (length-delimited)."""
    if isinstance(value, int):
        return _varint(number << 3) + _varint(value)
    data = value.encode() if isinstance(value, str) else value
    return _varint((number << 3) | 2) + _varint(len(data)) + data


def _value_info(name: str, dims) -> bytes:
    shape = b"".join(_field(1, _field(2, "N") if d < 0 else _field(1, d)) for d in dims)
    tensor = _field(1, 1) + _field(2, shape)  # FLOAT
    return _field(1, name) + _field(2, _field(1, tensor))


def _int64s(name: str, values) -> bytes:
    raw = b"".join(int(v).to_bytes(8, "little", signed=True) for v in values)
    return _field(1, len(values)) + _field(2, 7) + _field(8, name) + _field(9, raw)


def _node(op: str, inputs, output: str) -> bytes:
    return b"".join(_field(1, i) for i in inputs) + _field(2, output) + _field(3, output) + _field(4, op)


def failing_decoder(latent: int, features: int) -> bytes:
    """An ONNX graph with the decoder's interface that ONNX Runtime cannot run for any
    number of query points but 7 (``Reshape`` of the rows' sums to ``[7, 1]``); written as
    protobuf field by field (as ``tests/rom_faults.rs`` does)."""
    graph = (
        _field(1, _node("ReduceSum", ["query", "axes"], "sum"))
        + _field(1, _node("Reshape", ["sum", "rows"], "depth"))
        + _field(2, "fails-unless-seven-rows")
        + _field(5, _int64s("axes", [1]))
        + _field(5, _int64s("rows", [7, 1]))
        + _field(11, _value_info("z", [1, latent]))
        + _field(11, _value_info("query", [-1, features]))
        + _field(12, _value_info("depth", [-1, 1]))
    )
    return _field(1, 8) + _field(2, "tacrom-tests") + _field(7, graph) + _field(8, _field(1, "") + _field(2, 17))


def test_onnx_runtime_failing_every_call_of_a_coupled_sensor(press_xml, tmp_path, capfd):
    """Catches: an error from ONNX Runtime's run that crashes the host, leaves NaN in
    ``sensordata`` or ``qfrc_passive``, or goes unreported. The shipped model with a decoder
    that loads (its interface is the manifest's) but fails every call, on a gel that pushes
    back (``coupling="on"``): MuJoCo steps on, the sensor warns naming the decoder and
    falls back to the coarse surface, and its outputs and the gel's push-back stay finite."""
    import json

    model_dir = tmp_path / "rom"
    shutil.copytree(ROOT / "models" / "rom-default", model_dir)
    manifest = json.loads((model_dir / "manifest.json").read_text())
    assert manifest["files"]["decoder"]["path"] == "decoder.onnx"
    (model_dir / "decoder.onnx").write_bytes(
        failing_decoder(manifest["latent"], manifest["query_features"]))
    xml = with_config(press_xml, physics="rom", model=str(model_dir), outputs="depth force",
                      resolution="64 48", coupling="on")
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    forces = []
    for k in range(5):
        out = evaluate(m, d, 0.1e-3 * (k + 1))
        mujoco.mj_step(m, d)
        assert np.isfinite(d.sensordata).all() and np.isfinite(d.qfrc_passive).all()
        assert out["depth"].max() > 0
        forces.append(out["force"][2])
    assert all(b > a > 0 for a, b in zip(forces, forces[1:])), forces
    err = capfd.readouterr().err
    assert "'touch'" in err and "ONNX Runtime failed running decoder" in err, err
    assert "coarse depth used" in err, err
