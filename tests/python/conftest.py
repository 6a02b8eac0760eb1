import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture
def press_xml() -> str:
    return (ROOT / "examples" / "press.xml").read_text()


def with_config(xml: str, **config: str) -> str:
    """The press example with its sensor's <config> entries replaced by ``config``."""
    import re

    start = xml.index('<plugin name="touch"')
    end = xml.index("</plugin>", start)
    head = xml[start : xml.index(">", start) + 1]
    body = "".join(f'<config key="{k}" value="{v}"/>' for k, v in config.items())
    return xml[:start] + head + body + xml[end:]


def evaluate(model, data, depth_m):
    """Places the press joint at ``depth_m`` (positive into the gel), evaluates the sensor
    and returns all its outputs."""
    import mujoco

    import tacrom

    data.qpos[0] = depth_m
    mujoco.mj_forward(model, data)
    return tacrom.outputs(model, data, "touch")


def in_threads(fn, args):
    """``[fn(a) for a in args]``, each call in its own thread, all running at once."""
    import threading

    results = [None] * len(args)

    def worker(i):
        results[i] = fn(args[i])

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(len(args))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return results
