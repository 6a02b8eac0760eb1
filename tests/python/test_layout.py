"""The plugin crate's files depend on each other without cycles.

Each file of ``src/`` is a module; a path it names (``crate::a::b``, ``super::c``,
``self::d``, grouped imports ``use super::{e, f::g}`` expanded) outside comments and its
test module is an edge to the deepest module the path reaches. A cycle of edges between
files would tie their concerns together. A parent module names its children without a
prefix (``surface::surface_depth`` in ``mpm/mod.rs``): those paths are not read, so a parent
and its children (one concern, the parent's types implemented in its files) make no cycle.
"""

from __future__ import annotations

import pathlib
import re

SRC = pathlib.Path(__file__).resolve().parents[2] / "src"


def module_of(path: pathlib.Path) -> tuple[str, ...]:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] in ("mod", "lib"):
        parts.pop()
    return tuple(parts)


def code_of(text: str) -> str:
    """The file's code without comments and without its test module."""
    text = re.split(r"#\[cfg\(test\)\]\s*mod\s+\w+\s*\{", text)[0]
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    return re.sub(r"//[^\n]*", "", text)


def paths_in(code: str) -> list[list[str]]:
    """Every path rooted at ``crate``, ``super`` or ``self``, grouped imports expanded."""
    out = []
    for m in re.finditer(r"\b(crate|super|self)\s*::", code):
        head, i = [m.group(1)], m.end()
        out.extend(expand(code, i, head))
    return out


def expand(code: str, i: int, prefix: list[str]) -> list[list[str]]:
    """The paths that continue ``prefix`` at ``code[i:]`` (after a ``::``)."""
    while code[i].isspace():
        i += 1
    if code[i] == "{":
        paths, depth, start = [], 0, i + 1
        for j in range(i, len(code)):
            depth += {"{": 1, "}": -1}.get(code[j], 0)
            if depth == 0:
                break
        for item in split_top(code[start:j]):
            item = item.strip()
            if item:
                paths.extend(expand(item + " ", 0, prefix))
        return paths
    m = re.match(r"(\w+)((?:\s*::\s*\w+)*)(\s*::\s*)?", code[i:])
    if not m:
        return [prefix]
    segments = prefix + [m.group(1)] + re.findall(r"\w+", m.group(2))
    if m.group(3):
        return expand(code, i + m.end(), segments)
    return [segments]


def split_top(s: str) -> list[str]:
    """``s`` split at the commas outside braces."""
    parts, depth, start = [], 0, 0
    for k, c in enumerate(s):
        depth += {"{": 1, "}": -1}.get(c, 0)
        if c == "," and depth == 0:
            parts.append(s[start:k])
            start = k + 1
    parts.append(s[start:])
    return parts


def edges() -> dict[tuple[str, ...], set[tuple[str, ...]]]:
    files = {module_of(p): p for p in SRC.rglob("*.rs")}
    graph: dict[tuple[str, ...], set[tuple[str, ...]]] = {m: set() for m in files}
    for me, path in files.items():
        for segments in paths_in(code_of(path.read_text())):
            head, rest = segments[0], segments[1:]
            base = list(me)
            if head == "crate":
                base = []
            elif head == "super":
                base = base[:-1]
            while rest and rest[0] == "super":
                base, rest = base[:-1], rest[1:]
            full = base + rest
            target = next(
                (tuple(full[:k]) for k in range(len(full), 0, -1) if tuple(full[:k]) in files),
                None,
            )
            if target is not None and target != me:
                graph[me].add(target)
    return graph


def cycles(graph) -> list[list[tuple[str, ...]]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(component)

    for v in graph:
        if v not in index:
            visit(v)
    return found


def test_the_reader_follows_grouped_and_relative_imports():
    code = "use super::{pressure::ContactLoad, Gel, solver::{Frame, Equilibrium}};\ncrate::a::b();"
    assert paths_in(code) == [
        ["super", "pressure", "ContactLoad"],
        ["super", "Gel"],
        ["super", "solver", "Frame"],
        ["super", "solver", "Equilibrium"],
        ["crate", "a", "b"],
    ]
    # Comments and the test module name nothing.
    assert paths_in(code_of("// crate::x\nfn f() {}\n#[cfg(test)]\nmod tests {\n crate::y();\n}")) == []


def test_the_plugin_files_have_no_cycles():
    graph = edges()
    # The reader sees the crate's structure (a failure here means it reads nothing).
    assert ("sensor",) in graph[("mujoco", "plugin")] or any(
        t[0] == "sensor" for t in graph[("mujoco", "plugin")]
    )
    assert sum(len(v) for v in graph.values()) > 100
    found = cycles(graph)
    assert not found, "files that depend on each other in a cycle: " + "; ".join(
        " -> ".join("::".join(m) or "lib" for m in c) for c in found
    )


def test_a_cycle_is_found():
    graph = {("a",): {("b",)}, ("b",): {("c",)}, ("c",): {("a",)}, ("d",): {("a",)}}
    assert [sorted(c) for c in cycles(graph)] == [[("a",), ("b",), ("c",)]]
