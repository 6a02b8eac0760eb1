"""The wheel (python/build_wheel.py, `make wheel`): what it holds, and that it works when
installed into a fresh virtual environment and used from outside the checkout.

The fresh environment is a plain venv (no system or checkout site-packages) filled
offline, with ``pip install --no-index``, from a wheelhouse of the pinned MuJoCo, NumPy,
Gymnasium and ONNX Runtime wheels (``$TACROM_WHEELHOUSE`` or ``target/wheelhouse``, made
with ``pip download`` when it lacks them). Where that is impossible (no network and no
wheelhouse), the test says so with a warning and installs the tacrom wheel with
``--no-deps`` into a venv that sees the build's ``.venv`` site-packages through a .pth file.
"""

import json
import os
import pathlib
import subprocess
import sys
import sysconfig
import textwrap
import warnings
import zipfile

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "python"))
import build_wheel  # noqa: E402

REQUIREMENTS = ("mujoco", "mujoco-core", "numpy", "gymnasium", "onnxruntime")


def pinned() -> list:
    """The pins of python/requirements.txt for what the wheel's install needs."""
    pins = []
    for line in (ROOT / "python" / "requirements.txt").read_text().splitlines():
        name = line.split("==")[0].strip().lower()
        if name in REQUIREMENTS:
            pins.append(line.strip())
    assert len(pins) == len(REQUIREMENTS), pins
    return pins


def wheelhouse() -> pathlib.Path | None:
    """A folder holding the pinned wheels and their dependencies, or None when it cannot be
    made here."""
    house = pathlib.Path(os.environ.get("TACROM_WHEELHOUSE", ROOT / "target" / "wheelhouse"))
    house.mkdir(parents=True, exist_ok=True)
    pip = [sys.executable, "-m", "pip", "download", "-q", "--only-binary=:all:", "-d", str(house)]
    offline = subprocess.run(
        [*pip, "--no-index", "--find-links", str(house), *pinned()], capture_output=True
    )
    if offline.returncode == 0:
        return house
    online = subprocess.run([*pip, *pinned()], capture_output=True, timeout=600)
    return house if online.returncode == 0 else None


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> pathlib.Path:
    return build_wheel.build(tmp_path_factory.mktemp("dist"))


def test_the_wheel_holds_the_library_the_model_and_the_package(wheel):
    platform = sysconfig.get_platform().replace("-", "_").replace(".", "_")
    assert wheel.name == f"tacrom-0.1.0-py3-none-{platform}.whl"
    names = set(zipfile.ZipFile(wheel).namelist())
    for name in [
        "tacrom/__init__.py",
        "tacrom/env.py",
        "tacrom/envs/__init__.py",
        "tacrom/envs/base.py",
        "tacrom/envs/press.py",
        "tacrom/envs/gripper.py",
        "tacrom/envs/assets/gripper.xml",
        "tacrom/envs/assets/meshes/hexagon.stl",
        "tacrom/envs/assets/meshes/LICENSE",
        "tacrom/_lib/libtacrom.so",
        "tacrom/models/rom-default/manifest.json",
        "tacrom/models/rom-default/encoder.onnx",
        "tacrom/models/rom-default/decoder.onnx",
        "tacrom/models/rom-default/decoder_jacobian.onnx",
        "tacrom/models/rom-linear/manifest.json",
        "tacrom/models/rom-linear/encoder.onnx",
        "tacrom/models/rom-linear/decoder_int8.onnx",
        "tacrom/models/rom-linear/decoder_jacobian.onnx",
        "tacrom/models/rom-linear-narrow/manifest.json",
        "tacrom/models/rom-linear-narrow/encoder.onnx",
        "tacrom/models/rom-linear-narrow/decoder.onnx",
        "tacrom/models/rom-linear-narrow/decoder_jacobian.onnx",
        "tacrom/sensors/gelsight-mini/sensor.json",
        "tacrom/sensors/gelsight-mini/optics.json",
        "tacrom/sensors/gelsight-mini/LICENSE-taxim",
    ]:
        assert name in names, name
    # Training artefacts stay out, and so does the float decoder that rom-linear's 8-bit
    # one replaces (its manifest names only the files the run time loads).
    assert not [n for n in names if n.endswith(".pt") or "/validation/" in n]
    assert "tacrom/models/rom-linear/decoder.onnx" not in names
    with zipfile.ZipFile(wheel) as z:
        entry_points = z.read("tacrom-0.1.0.dist-info/entry_points.txt").decode()
        manifest = json.loads(z.read("tacrom/models/rom-default/manifest.json"))
        linear = json.loads(z.read("tacrom/models/rom-linear/manifest.json"))
        narrow = json.loads(z.read("tacrom/models/rom-linear-narrow/manifest.json"))
        lib = z.read("tacrom/_lib/libtacrom.so")
    assert "[mujoco.plugins]" in entry_points and "tacrom:_register_with_mujoco" in entry_points
    assert manifest["format"] == "tacrom-rom-1"
    assert manifest["recipe"]["solver"] == "relaxation"
    assert linear["recipe"]["solver"] == "linear"
    assert narrow["recipe"]["solver"] == "linear" and narrow["decoder_hidden"] == [128, 64, 32]
    assert lib == (ROOT / "python" / "tacrom" / "_lib" / "libtacrom.so").read_bytes()


# Run in the fresh environment, from a folder outside the checkout: the press scene pressed
# 0.8 mm (rigid, then rom with the wheel's models: "rom" the default, the linear gel's,
# "rom:relaxation" the relaxation's), and the gripper environment from the wheel's scene.
SCRIPT = textwrap.dedent(
    """
    import json, pathlib, sys
    import mujoco
    import tacrom

    PRESS = '''
    <mujoco>
      <extension><plugin plugin="tacrom.tactile"/></extension>
      <option gravity="0 0 0"/>
      <worldbody>
        <body name="sensor"><site name="gel"/></body>
        <body name="ball" pos="0 0 0.005">
          <joint name="press" type="slide" axis="0 0 -1"/>
          <geom type="sphere" size="0.005" mass="0.01" contype="0" conaffinity="0"/>
        </body>
      </worldbody>
      <sensor>
        <plugin name="touch" plugin="tacrom.tactile" objtype="site" objname="gel">
          <config key="physics" value="PHYSICS"/>
          SOLVER
          <config key="resolution" value="32 24"/>
        </plugin>
      </sensor>
    </mujoco>
    '''
    result = {"tacrom": tacrom.__file__, "library": str(tacrom.library_path())}
    for spec in sys.argv[1].split(","):
        physics, _, solver = spec.partition(":")
        xml = PRESS.replace("PHYSICS", physics).replace(
            "SOLVER", f'<config key="solver" value="{solver}"/>' if solver else ""
        )
        model = mujoco.MjModel.from_xml_string(xml)
        data = mujoco.MjData(model)
        data.qpos[0] = 0.0008
        mujoco.mj_forward(model, data)
        result[spec] = float(tacrom.depth(model, data, "touch").max())
    if len(sys.argv) > 2:
        import gymnasium as gym
        from tacrom.envs.base import asset_path
        env = gym.make("tacrom/GripperLift-v1", object="hexagon")
        env.reset(seed=0)
        result["gripper_scene"] = str(asset_path("gripper.xml"))
        for action in [[0, -1, -1]] * 15 + [[0, -1, 1]] * 10:
            obs, *_ = env.step(action)
        result["gripper_depth"] = float(obs["tactile_depth"].max())
    print(json.dumps(result))
    """
)


def run_outside(python: pathlib.Path, cwd: pathlib.Path, *args: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "TACROM_PLUGIN")}
    env["MUJOCO_GL"] = "disable"
    script = cwd / "press.py"
    script.write_text(SCRIPT)
    done = subprocess.run(
        [str(python), str(script), *args], cwd=cwd, env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_the_installed_wheel_presses_from_outside_the_checkout(wheel, tmp_path):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    pip = [sys.executable, "-m", "pip", "--python", str(python), "install", "-q"]
    house = wheelhouse()
    if house is not None:
        subprocess.run(
            [*pip, "--no-index", "--find-links", str(house), f"{wheel}[rl,rom]"], check=True
        )
    else:
        warnings.warn(
            "no wheelhouse of the pinned MuJoCo wheels could be made (offline, none cached): "
            "the wheel is installed with --no-deps into a venv that sees the build's .venv"
        )
        site = subprocess.run(
            [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            capture_output=True, text=True, check=True,
        ).stdout.strip()
        build_site = sysconfig.get_paths()["purelib"]
        # After the venv's own site-packages, so the installed tacrom wins over the
        # checkout's editable one.
        pathlib.Path(site, "zz_build_venv.pth").write_text(build_site + "\n")
        subprocess.run([*pip, "--no-deps", str(wheel)], check=True)

    outside = tmp_path / "elsewhere"
    outside.mkdir()
    result = run_outside(python, outside, "rigid,rom,rom:relaxation", "gripper")
    installed = venv.resolve()
    assert pathlib.Path(result["tacrom"]).resolve().is_relative_to(installed), result
    assert pathlib.Path(result["library"]).resolve().is_relative_to(installed), result
    assert pathlib.Path(result["gripper_scene"]).resolve().is_relative_to(installed), result
    assert result["rigid"] > 5e-4 and result["rom"] > 5e-4 and result["rom:relaxation"] > 5e-4, result
    assert result["gripper_depth"] > 3e-4, result

    # The library reads the model inside the installed package (not the checkout's): with
    # that copy of rom's default on the default gel (the linear gel's narrow decoder)
    # broken, rom fails to load.
    site = pathlib.Path(result["tacrom"]).parent
    manifest = site / "models" / "rom-linear-narrow" / "manifest.json"
    manifest.write_text("{}")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "TACROM_PLUGIN")}
    broken = subprocess.run(
        [str(python), str(outside / "press.py"), "rom"], cwd=outside, env=env,
        capture_output=True, text=True,
    )
    assert broken.returncode != 0
    assert "manifest" in broken.stderr, broken.stderr
