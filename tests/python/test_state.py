"""Sensor state per MjData through the real `mujoco` Python package: mj_resetData restores
the undeformed gel after a frictional slide, mj_copyData carries a gel with history, and
an off-centre press lands where the documented image layout says.

Each scene is cheap: a coarse gel, 32 x 24 images, presses of at most 1 mm."""

import mujoco
import numpy as np

import tacrom

W, H = 32, 24
FOV = (0.024, 0.018)
R = 0.005

# A fixed sensor (site "gel", top face at z = 0) and a sphere on three slide joints:
# qpos = [x, y, press], the sphere touching the gel at qpos = 0.
SCENE = """
<mujoco>
  <extension><plugin plugin="tacrom.tactile"/></extension>
  <option gravity="0 0 0"/>
  <worldbody>
    <body name="sensor">
      <geom name="pad" type="box" size="0.015 0.015 0.002" pos="0 0 -0.006"/>
      <site name="gel"/>
    </body>
    <body name="indenter" pos="0 0 {lift}">
      <joint name="x" type="slide" axis="1 0 0"/>
      <joint name="y" type="slide" axis="0 1 0"/>
      <joint name="press" type="slide" axis="0 0 -1"/>
      {geom}
    </body>
  </worldbody>
  <sensor>
    <plugin name="touch" plugin="tacrom.tactile" objtype="site" objname="gel">
      <config key="physics" value="{physics}"/>
      <config key="outputs" value="{outputs}"/>
      <config key="resolution" value="{W} {H}"/>
      <config key="friction" value="1.0"/>
    </plugin>
  </sensor>
</mujoco>
"""
SPHERE = f'<geom type="sphere" size="{R}" contype="0" conaffinity="0"/>'

# A deep frictional press slid 1.5 mm sideways (a gel with history), then a shallow press
# under the slid sphere.
HISTORY = [(0, 0, 0.5e-3), (0, 0, 1.0e-3), (0.5e-3, 0, 1.0e-3), (1.0e-3, 0, 1.0e-3),
           (1.5e-3, 0, 1.0e-3), (1.5e-3, 0.2e-3, 0.9e-3)]
SHALLOW = (1.5e-3, 0.2e-3, 0.2e-3)


def model(physics="coarse", outputs="depth force", geom=SPHERE, lift=R):
    xml = SCENE.format(lift=lift, geom=geom, physics=physics, outputs=outputs, W=W, H=H)
    return mujoco.MjModel.from_xml_string(xml)


def evaluate(m, d, pose):
    """All outputs of the sensor with the indenter at ``pose`` = (x, y, press)."""
    d.qpos[:3] = pose
    mujoco.mj_forward(m, d)
    out = tacrom.outputs(m, d, "touch")
    return {k: np.array(v, copy=True) for k, v in out.items()}


def assert_same(a, b, what):
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=f"{what}: {k}")


def history_shows(a, b, press):
    """Whether two outputs differ by more than 10 % of the press depth or of the force."""
    fz = b["force"][2]
    return (np.abs(a["depth"] - b["depth"]).max() > 0.1 * press
            or np.abs(a["force"] - b["force"]).max() > 0.1 * fz)


def test_reset_after_frictional_slide_equals_fresh_gel():
    """Catches: mj_resetData leaving gel state behind (a no-op or partial reset). After a
    deep frictional slide and a reset, one shallow press must equal a fresh MjData's, bit
    for bit: the same deterministic computation on the same input; and without the reset
    the same press differs (the history is real, so the test has teeth)."""
    m = model()
    d = mujoco.MjData(m)
    for pose in HISTORY:
        evaluate(m, d, pose)
    kept = mujoco.MjData(m)
    mujoco.mj_copyData(kept, m, d)
    with_history = evaluate(m, kept, SHALLOW)

    mujoco.mj_resetData(m, d)
    after_reset = evaluate(m, d, SHALLOW)
    fresh = evaluate(m, mujoco.MjData(m), SHALLOW)
    assert fresh["force"][2] > 0.0
    assert_same(after_reset, fresh, "reset gel vs fresh gel")
    assert history_shows(with_history, fresh, SHALLOW[2])


def test_copy_continues_identically_and_keeps_history():
    """Catches: mj_copyData not carrying the gel (a fresh sensor in the copy, a shared or
    partial state). Original and copy continue one frictional trajectory and agree bit for
    bit every frame (the same deterministic computation from the same state); the copy's
    last frame differs from a fresh gel pressed straight to the final pose."""
    m = model()
    original = mujoco.MjData(m)
    for pose in HISTORY[:4]:
        evaluate(m, original, pose)
    copy = mujoco.MjData(m)
    mujoco.mj_copyData(copy, m, original)
    rest = HISTORY[4:] + [SHALLOW]
    for i, pose in enumerate(rest):
        a = evaluate(m, original, pose)
        b = evaluate(m, copy, pose)
        assert a["depth"].max() > 0.0
        assert_same(a, b, f"frame {i} after the copy")
    fresh = evaluate(m, mujoco.MjData(m), SHALLOW)
    assert history_shows(b, fresh, SHALLOW[2])


def test_off_centre_box_lands_at_documented_pixels():
    """Catches: a mirrored or transposed image. A box 6 x 2 mm (long along x) pressed at
    (+5, +3) mm must appear where the documented layout puts it (row 0 the +y edge,
    column 0 the -x edge): its depth-weighted centroid within one pixel (0.75 mm) of the
    box centre (the footprint is symmetric about it; a flipped axis moves it 10 or 6 mm),
    and the footprint wider than tall."""
    box = ('<geom type="box" size="0.003 0.001 0.001" pos="0.005 0.003 0.001" '
           'contype="0" conaffinity="0"/>')
    for physics in ("rigid", "coarse"):
        m = model(physics=physics, outputs="depth", geom=box, lift=0.0)
        depth = evaluate(m, mujoco.MjData(m), (0, 0, 0.3e-3))["depth"]
        assert depth.shape == (H, W) and depth.max() > 0.2e-3
        x = -FOV[0] / 2 + (np.arange(W) + 0.5) * FOV[0] / W
        y = FOV[1] / 2 - (np.arange(H) + 0.5) * FOV[1] / H
        total = depth.sum()
        cx = (depth.sum(axis=0) * x).sum() / total
        cy = (depth.sum(axis=1) * y).sum() / total
        pixel = FOV[0] / W
        assert abs(cx - 0.005) < pixel and abs(cy - 0.003) < pixel, (physics, cx, cy)
        vx = (depth.sum(axis=0) * (x - cx) ** 2).sum() / total
        vy = (depth.sum(axis=1) * (y - cy) ** 2).sum() / total
        assert vx > 2 * vy, (physics, vx, vy)
