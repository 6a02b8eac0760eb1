"""The mode names the example scripts take (``--physics``): a physics (``rigid``,
``coarse``, ``fine``, ``rom``), optionally followed by a dash and either a solver's name
(``coarse-linear``: ``solver="linear"``) or the rest of one of rom's shipped models' names
(``rom-default``: ``model="rom-default"``, rom on the relaxation with the linear solver for
contacts it misses, as ``physics="rom"`` ran before its default became the linear gel)."""

SOLVERS = ("relaxation", "newton", "total", "linear")


def mode_config(mode: str) -> dict:
    """The sensor attributes of ``mode``: ``physics`` and, after a dash, ``solver`` or
    ``model``."""
    physics, _, rest = mode.partition("-")
    config = {"physics": physics}
    if rest in SOLVERS:
        config["solver"] = rest
    elif rest:
        config["model"] = mode
    return config
