"""A process forked after a gel has been solved (as gymnasium's AsyncVectorEnv and
multiprocessing's default start method do) must be able to solve gels itself: every
parallel pass of a one-thread solve runs on the calling thread, never in a thread pool the
child would not have."""

import multiprocessing as mp

import mujoco

from conftest import evaluate, with_config


def _press(xml: str) -> float:
    model = mujoco.MjModel.from_xml_string(xml)
    return float(evaluate(model, mujoco.MjData(model), 0.4e-3)["force"][2])


def test_a_forked_child_solves_after_the_parent_did(press_xml):
    xml = with_config(press_xml, physics="coarse", outputs="depth force", resolution="32 24")
    parent = _press(xml)
    assert parent > 0.0
    with mp.get_context("fork").Pool(1) as pool:
        child = pool.apply_async(_press, (xml,)).get(timeout=120)
    # The same press from rest: bit for bit the parent's force.
    assert child == parent
