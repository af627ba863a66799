#!/usr/bin/env python3
"""Import cycles between the modules of both crates, and the layering rules of
docs/architecture.md, read from the source's `use` paths and inline `crate::` paths.

A module is a file (`foo.rs`, or `foo/mod.rs` for the folder). An edge A -> B means a path in A
names an item of B (`crate::b::…`, `super::…`, `infraloc_core::…`). Test modules (`#[cfg(test)]
mod tests { … }` to the end of the file) and doc comments are left out: tests may reach across.
Exits 1 and prints every cycle (strongly connected component of more than one module) and every
broken layering rule; prints a one-line summary otherwise. `--root DIR` reads the two crates of
another checkout (`DIR/core/src`, `DIR/src`): the layering test runs it on a tree with a known
cycle.
"""
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def modules(crate_dir, crate_name):
    """{module path tuple: file} of one crate's src/."""
    out = {}
    src = os.path.join(ROOT, crate_dir, "src")
    for d, _, fs in os.walk(src):
        for f in fs:
            if not f.endswith(".rs"):
                continue
            rel = os.path.relpath(os.path.join(d, f), src)[:-3].split(os.sep)
            if rel[-1] == "mod":
                rel = rel[:-1]
            if rel in (["lib"], ["main"]):
                rel = []
            out[(crate_name,) + tuple(rel)] = os.path.join(d, f)
    return out


def strip(text):
    """Source without comments and without the trailing test module."""
    m = re.search(r"^#\[cfg\(test\)\]\s*\n\s*mod \w+ \{", text, re.M)
    if m:
        text = text[: m.start()]
    text = re.sub(r"//[^\n]*", "", text)
    return text


def resolve(mods, start, parts):
    """The longest known module prefix of `parts` (a path from a crate root)."""
    for k in range(len(parts), -1, -1):
        if start + tuple(parts[:k]) in mods:
            return start + tuple(parts[:k])
    return None


def edges(mods):
    graph = {m: set() for m in mods}
    path_re = re.compile(r"\b(crate|super|infraloc_core|infraloc)((?:::\w+)+|::\{)")
    for m, f in mods.items():
        text = strip(open(f, encoding="utf-8").read())
        # expand grouped imports: use a::{b, c::d} -> a::b, a::c::d (one level is enough here)
        for g in re.finditer(r"\b((?:crate|super|infraloc_core|infraloc)(?:::\w+)*)::\{([^{}]*)\}", text):
            for item in g.group(2).split(","):
                item = item.strip().split(" as ")[0]
                if item and item != "self":
                    text += f"\n{g.group(1)}::{item}"
        for p in path_re.finditer(text):
            head, rest = p.group(1), [x for x in p.group(2).split("::") if x and x != "{"]
            if head == "crate":
                target = resolve(mods, (m[0],), rest)
                if m[0] == "infraloc" and target == ("infraloc",) and rest:
                    target = resolve(mods, ("infraloc_core",), rest)
            elif head == "super":
                # `super` is the parent of the module the file is, whether the file is a leaf
                # (`a/b.rs`: module a::b, super = a) or a folder's `mod.rs` (`a/mod.rs`: module a,
                # super = the crate root).
                base = m[:-1]
                while rest and rest[0] == "super":
                    base, rest = base[:-1], rest[1:]
                target = resolve(mods, base, rest)
            elif head == "infraloc_core":
                target = resolve(mods, ("infraloc_core",), rest)
            else:
                target = resolve(mods, ("infraloc",), rest)
            if target is not None and target[0] == "infraloc" and len(target) == 1 and rest:
                # the application's re-exports of core modules (`pub use infraloc_core::{…}`)
                target = resolve(mods, ("infraloc_core",), rest)
            if target and target != m and target[1:] != ():
                graph[m].add(target)
    return graph


def sccs(graph):
    index, low, stack, on, out, n = {}, {}, [], set(), [], [0]
    sys.setrecursionlimit(10000)

    def visit(v):
        index[v] = low[v] = n[0]
        n[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            out.append(comp)

    for v in graph:
        if v not in index:
            visit(v)
    return [c for c in out if len(c) > 1]


# The search and objective code the service must reach only through the core's drift check.
SEARCH_CODE = {
    ("infraloc_core", "localize", "mi", m) for m in ("objective", "space", "kernel")
} | {("infraloc_core", "localize", "refine", m) for m in ("search", "polish", "uncertainty", "rounds")}


def name(m):
    return "::".join(m)


def main():
    global ROOT
    if len(sys.argv) == 3 and sys.argv[1] == "--root":
        ROOT = os.path.abspath(sys.argv[2])
    elif len(sys.argv) != 1:
        print("usage: module_cycles.py [--root DIR]", file=sys.stderr)
        return 2
    mods = modules("core", "infraloc_core")
    mods.update(modules(".", "infraloc"))
    graph = edges(mods)
    problems = []
    for comp in sccs(graph):
        problems.append("cycle: " + " <-> ".join(sorted(name(m) for m in comp)))
    for m, ts in graph.items():
        for t in ts:
            if m[:3] == ("infraloc_core", "localize", "init") and t[:3] == ("infraloc_core", "localize", "refine"):
                problems.append(f"layering: {name(m)} imports {name(t)} (init/ must not import refine/)")
            if m[:2] == ("infraloc", "daemon") and t[:4] in SEARCH_CODE:
                problems.append(f"layering: {name(m)} imports {name(t)} (the service holds no search or objective code)")
    for p in problems:
        print(p)
    n_edges = sum(len(v) for v in graph.values())
    if problems:
        print(f"{len(problems)} problem(s) in {len(mods)} modules, {n_edges} imports")
        return 1
    print(f"no import cycle, layering holds: {len(mods)} modules, {n_edges} imports")
    return 0


if __name__ == "__main__":
    sys.exit(main())
