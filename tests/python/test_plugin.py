"""The plugin through the real `mujoco` Python package: registration by entry point, the
press example, state handling, threads, and bad input."""

import mujoco
import numpy as np
import pytest

import tacrom
from conftest import evaluate, in_threads, with_config

DEFAULT = dict(physics="rigid", outputs="depth", resolution="320 240")


def press(model, data, depth_m):
    """The depth image with the press joint at ``depth_m``."""
    return evaluate(model, data, depth_m)["depth"]


def test_import_mujoco_registers_the_plugin(press_xml):
    # Only `import mujoco` ran (tacrom's entry point); the model compiles.
    model = mujoco.MjModel.from_xml_string(press_xml)
    assert model.nplugin == 1


def test_press_example_steps_and_depth_behaves(press_xml):
    model = mujoco.MjModel.from_xml_string(press_xml)
    data = mujoco.MjData(model)
    img = tacrom.depth(model, data, "touch")
    assert img.shape == (240, 320)
    mujoco.mj_forward(model, data)
    assert np.all(tacrom.depth(model, data, "touch") == 0.0)  # ctrl 0: just touching
    peaks = []
    for target in (0.2e-3, 0.5e-3, 1.0e-3):
        data.ctrl[0] = target
        for _ in range(300):
            mujoco.mj_step(model, data)
        img = tacrom.depth(model, data, "touch")
        assert np.all(np.isfinite(img)) and img.min() >= 0.0
        peaks.append(img.max())
        # The actuator tracks the target: the peak equals the joint's press.
        assert abs(img.max() - data.qpos[0]) < 2e-5
    assert peaks[0] < peaks[1] < peaks[2]
    assert abs(peaks[2] - 1.0e-3) < 5e-5


def test_two_threads_match_sequential(press_xml):
    model = mujoco.MjModel.from_xml_string(with_config(press_xml, **{**DEFAULT, "resolution": "80 60"}))
    depths = [0.15e-3, 0.35e-3, 0.55e-3, 0.8e-3]
    sequential = [press(model, mujoco.MjData(model), d) for d in depths]
    results = in_threads(lambda d: press(model, mujoco.MjData(model), d), depths)
    for a, b in zip(sequential, results):
        np.testing.assert_array_equal(a, b)


def test_layout_and_outputs(press_xml):
    xml = with_config(press_xml, physics="rigid", outputs="contact depth", resolution="40 30")
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    lay = tacrom.layout(model, "touch")
    assert lay["width"] == 40 and lay["height"] == 30
    assert lay["size"] == 2400
    assert lay["outputs"] == {
        "contact": {"offset": 0, "shape": (30, 40), "unit": "1"},
        "depth": {"offset": 1200, "shape": (30, 40), "unit": "m"},
    }
    img = press(model, data, 0.4e-3)
    mask = tacrom.contact(model, data, "touch")
    np.testing.assert_array_equal(mask, (img > 0).astype(float))
    with pytest.raises(KeyError, match="force"):
        tacrom.force(model, data, "touch")


@pytest.mark.parametrize(
    "key,value",
    [
        ("physics", "magic"),
        ("size", "-0.03 0.03 0.004"),
        ("resolution", "0 240"),
        ("resolution", "lots of pixels"),
        ("fov", "garbage"),
        ("young", "-5"),
        ("poisson", "0.7"),
        ("threads", "0"),
        ("outputs", "depth pressure"),
        ("outputs", "depth shear"),
        ("outputs", "markers"),
        ("markers", "0 7"),
        ("markers", "nine seven"),
    ],
)
def test_bad_attribute_raises_naming_it(press_xml, key, value):
    config = {**DEFAULT, key: value}
    with pytest.raises(ValueError) as err:
        mujoco.MjModel.from_xml_string(with_config(press_xml, **config))
    msg = str(err.value)
    assert f"'{key}'" in msg and "'touch'" in msg and value in msg


def test_missing_site_raises(press_xml):
    xml = press_xml.replace('objname="gel"', 'objname="no_such_site"')
    with pytest.raises(ValueError, match="no_such_site"):
        mujoco.MjModel.from_xml_string(xml)


def test_process_survives_bad_input_and_keeps_working(press_xml):
    for _ in range(3):
        with pytest.raises(ValueError):
            mujoco.MjModel.from_xml_string(with_config(press_xml, physics="nope"))
    model = mujoco.MjModel.from_xml_string(press_xml)
    assert press(model, mujoco.MjData(model), 0.3e-3).max() > 0.29e-3


def test_nan_pose_gives_finite_output(press_xml):
    model = mujoco.MjModel.from_xml_string(press_xml)
    data = mujoco.MjData(model)
    data.qpos[0] = np.nan
    mujoco.mj_forward(model, data)
    assert np.all(np.isfinite(data.sensordata))
    assert press(model, data, 0.3e-3).max() > 0.29e-3


def _ordered_subsets(names):
    """Every non-empty subset of ``names``, in table order and reversed (2^n - 1 subsets,
    each output both before and after every other): what a layout bug depends on is which
    outputs precede which, not the full order (every permutation would be 13,699 loads for
    seven outputs)."""
    import itertools

    for k in range(1, len(names) + 1):
        for combo in itertools.combinations(names, k):
            yield combo
            if k > 1:
                yield combo[::-1]


def test_output_table_round_trip(press_xml):
    """The layout Python reads from the library places every output where the plugin writes
    it, for every subset of the table's outputs in both orders: each output read through
    the combined layout equals the same output of a sensor configured with it alone. The
    names, shapes and units come from the library's table; nothing is hard-coded here."""
    table = tacrom.output_table()
    names = [o["name"] for o in table]
    assert "depth" in names and len(names) == len(set(names))
    res = (20, 15)

    def run(combo):
        xml = with_config(
            press_xml, physics="coarse", outputs=" ".join(combo), resolution=f"{res[0]} {res[1]}"
        )
        model = mujoco.MjModel.from_xml_string(xml)
        data = mujoco.MjData(model)
        out = evaluate(model, data, 0.4e-3)
        lay = tacrom.layout(model, "touch")
        return model, out, lay

    alone = {name: run((name,))[1][name] for name in names}
    # One output depends by design on another being configured: rgb draws the markers.
    # Its reference with that one is the pair's own run.
    drawn = {"rgb": "markers"}
    together = {
        name: run((name, other))[1][name]
        for name, other in drawn.items()
        if name in names and other in names
    }
    nx, ny = run((names[0],))[2]["markers"]
    symbols = {"H": res[1], "W": res[0], "N": nx * ny}
    for row in table:
        shape = tuple(symbols.get(d, d) for d in row["shape"])
        assert alone[row["name"]].shape == shape, row
    for combo in _ordered_subsets(names):
        model, out, lay = run(combo)
        assert list(lay["outputs"]) == list(combo)
        assert lay["size"] == model.sensor_dim[0]
        offset = 0
        for name in combo:
            assert lay["outputs"][name]["offset"] == offset
            offset += int(np.prod(lay["outputs"][name]["shape"]))
            expected = together[name] if drawn.get(name) in combo else alone[name]
            np.testing.assert_array_equal(out[name], expected, err_msg=f"{name} in {combo}")
        assert offset == model.sensor_dim[0]


def test_shear_and_markers(press_xml):
    """The shear image and the markers through the real plugin: their shapes, markers at
    rest on their grid before contact, and a press that moves the markers around the
    contact outward and leaves the middle one in place."""
    xml = with_config(press_xml, physics="coarse", outputs="depth shear markers", resolution="40 30")
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    lay = tacrom.layout(model, "touch")
    nx, ny = lay["markers"]
    assert (nx, ny) == (9, 7)
    assert lay["outputs"]["shear"]["shape"] == (30, 40, 2)
    assert lay["outputs"]["markers"]["shape"] == (nx * ny, 4)

    evaluate(model, data, -1e-3)  # lifted: no contact
    rest = tacrom.markers(model, data, "touch")
    assert rest.shape == (nx * ny, 4)
    assert np.all(rest[:, 2:] == 0.0)
    np.testing.assert_allclose(rest[0, :2], [40 / nx / 2 - 0.5, 30 / ny / 2 - 0.5])
    grid = rest[:, :2].reshape(ny, nx, 2)
    assert np.all(np.diff(grid[:, :, 0], axis=1) > 0) and np.all(np.diff(grid[:, :, 1], axis=0) > 0)
    assert np.all(tacrom.shear(model, data, "touch") == 0.0)

    evaluate(model, data, 0.8e-3)
    moved = tacrom.markers(model, data, "touch")
    shear = tacrom.shear(model, data, "touch")
    assert shear.shape == (30, 40, 2) and np.abs(shear).max() > 1e-5
    mid = (ny // 2) * nx + nx // 2
    assert np.abs(moved[mid, 2:]).max() < 1e-7
    # The ring around the middle marker moves radially outward: right of it +x, above it +y
    # (the row above in the image), in pixels as in metres.
    right, above = mid + 1, mid - nx
    assert moved[right, 2] > 4e-6 and moved[right, 0] > rest[right, 0]
    assert moved[above, 3] > 4e-6 and moved[above, 1] < rest[above, 1]
    np.testing.assert_allclose(
        moved[:, 0] - rest[:, 0], moved[:, 2] / (0.024 / 40), rtol=1e-9, atol=1e-9
    )


def test_rigid_refuses_shear_and_markers(press_xml):
    for outputs, name in (("depth shear", "shear"), ("markers", "markers")):
        with pytest.raises(ValueError) as err:
            mujoco.MjModel.from_xml_string(with_config(press_xml, **{**DEFAULT, "outputs": outputs}))
        msg = str(err.value)
        assert "'touch'" in msg and "'outputs'" in msg and f"'{name}'" in msg and "physics" in msg


def test_rom_serves_other_gel_materials_and_refuses_others(press_xml):
    """The shipped reduced-order model through MuJoCo: a gel ten times stiffer gives the same
    image and ten times the force (its coarse depth does not depend on Young's modulus);
    Poisson's ratio and friction inside the ranges it was validated on (0.3 to 0.49, 0 to 1)
    load and press; Poisson 0.495 is refused at load, naming the sensor and both values."""
    rom = dict(physics="rom", outputs="depth force", resolution="64 48")
    runs = {}
    for name, extra in {"default": {}, "stiff": {"young": "1.19e6"},
                        "other": {"poisson": "0.32", "friction": "0.1"}}.items():
        model = mujoco.MjModel.from_xml_string(with_config(press_xml, **rom, **extra))
        out = evaluate(model, mujoco.MjData(model), 0.4e-3)
        runs[name] = (out["depth"], out["force"])
        assert np.all(np.isfinite(out["depth"])) and abs(out["depth"].max() - 0.4e-3) < 0.04e-3
        assert out["force"][2] > 0.0
    np.testing.assert_array_equal(runs["stiff"][0], runs["default"][0])
    np.testing.assert_allclose(runs["stiff"][1], 10.0 * runs["default"][1], rtol=1e-9, atol=1e-12)
    # A softer-in-volume gel (Poisson 0.32) carries less force at the same press.
    assert runs["other"][1][2] < runs["default"][1][2]
    with pytest.raises(ValueError) as err:
        mujoco.MjModel.from_xml_string(with_config(press_xml, **rom, poisson="0.495"))
    msg = str(err.value)
    assert "'touch'" in msg and "Poisson's ratio in [0.3, 0.49]" in msg and "0.495" in msg


def test_rom_serves_a_thin_gel_of_the_family_through_mujoco(press_xml):
    """The default physics (rom) on gels of the family other than the model's 30 x 30 x 4
    mm, through MuJoCo: the 5 mm ball pressed 0.2 mm into a GelSight Mini-sized gel
    (20.9 x 16.2 x 1.41 mm) and into a 12 x 12 x 1 mm one gives a finite image whose
    deepest pixel is the ball's deepest point within a tenth of the press, and a positive
    force; the thinner gel is the stiffer. A gel outside the family (50 mm across) is
    refused naming the sensor, the size and the family's ranges."""
    forces = {}
    for size in ["0.0209 0.0162 0.00141", "0.012 0.012 0.001"]:
        xml = with_config(press_xml, outputs="depth force", resolution="64 48", size=size,
                          fov="0.01 0.0075")
        model = mujoco.MjModel.from_xml_string(xml)
        out = evaluate(model, mujoco.MjData(model), 0.2e-3)
        depth = out["depth"]
        assert np.all(np.isfinite(depth)) and abs(depth.max() - 0.2e-3) < 0.02e-3, size
        forces[size] = out["force"][2]
        assert forces[size] > 0.0
    assert forces["0.012 0.012 0.001"] > forces["0.0209 0.0162 0.00141"]
    with pytest.raises(ValueError) as err:
        mujoco.MjModel.from_xml_string(with_config(press_xml, size="0.05 0.03 0.004"))
    msg = str(err.value)
    assert "'touch'" in msg and "'size'" in msg and "0.012 to 0.04 m across" in msg


def test_attribute_table_names_every_attribute_and_its_defaults_apply(press_xml):
    """The attribute table Python reads is the plugin's: every attribute MuJoCo accepts is
    in it once, and a sensor configured with each numeric default written out lays out and
    evaluates exactly as one that leaves them unset."""
    table = tacrom.attribute_table()
    names = [row["name"] for row in table]
    assert len(names) == len(set(names))
    assert {"physics", "outputs", "young", "poisson", "size", "solver"} <= set(names)
    defaults = {row["name"]: row["default"] for row in table}
    assert [float(x) for x in defaults["size"].split()] == [0.03, 0.03, 0.004]
    base = dict(physics="coarse", outputs="depth force", resolution="24 18")
    written = {k: defaults[k] for k in ("young", "poisson", "density", "friction", "size", "fov")}
    runs = []
    for extra in ({}, written):
        model = mujoco.MjModel.from_xml_string(with_config(press_xml, **base, **extra))
        data = mujoco.MjData(model)
        runs.append(evaluate(model, data, 0.4e-3))
    assert np.array_equal(runs[0]["depth"], runs[1]["depth"])
    assert np.array_equal(runs[0]["force"], runs[1]["force"])
    assert runs[0]["force"][2] > 0
    with pytest.raises(ValueError, match="'young'.*must be in \\[100, 1e10\\] Pa"):
        mujoco.MjModel.from_xml_string(with_config(press_xml, **base, young="1"))


def test_layout_names_the_gels_solver_and_why(press_xml):
    """The layout says which solver the plugin chose for the gel and the rule that chose it:
    the automatic rule below and above Poisson 0.49, a named solver as named, none for rigid,
    the linear gel for rom's shipped models."""
    def solver(**config):
        model = mujoco.MjModel.from_xml_string(with_config(press_xml, outputs="depth", **config))
        return tacrom.layout(model, "touch")["solver"]

    soft = solver(physics="coarse")
    assert soft["name"] == "relaxation" and soft["fallback"] is True
    assert "below 0.49" in soft["why"]
    stiff = solver(physics="coarse", poisson="0.495")
    assert stiff["name"] == "newton" and "0.49 or more" in stiff["why"]
    named = solver(physics="coarse", solver="linear")
    assert named == {"name": "linear", "fallback": False, "why": "named by the configuration"}
    assert solver(physics="rigid") is None
    # rom's default: the linear gel read by its own shipped model; the relaxation's rom
    # when named.
    rom = solver(physics="rom")
    assert rom["name"] == "linear" and rom["fallback"] is False
    assert "rom's default" in rom["why"]
    assert solver(physics="rom", solver="relaxation")["name"] == "relaxation"
