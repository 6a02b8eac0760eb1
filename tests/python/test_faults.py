"""Faults from outside the plugin, through the real `mujoco` package: a model file
truncated under a running sensor."""

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
