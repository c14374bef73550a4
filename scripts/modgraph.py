#!/usr/bin/env python3
"""Module graph of the tessera crate: import cycles, layering and function lengths.

    python3 scripts/modgraph.py [--check] [--dot FILE] [--max-fn-lines N]

Each source file is one module (`src/a/b.rs` and `src/a/b/mod.rs` are `crate::a::b`). An edge
A -> B means code in A names an item defined in B: a `use crate::…`/`super::…` import or a
`crate::…` path in code. Paths are resolved the way rustc resolves them for the purposes of
layering: a name re-exported by a module (`pub use b::Item;`) resolves to the module that
defines it, so `crate::pipeline::Tile` counts as a use of the file defining `Tile`. `mod x;`
declarations are ownership, not use. Test code (`#[cfg(test)]` modules and files) is skipped:
tests may reach anywhere.

With `--check` the script exits 1 when there is an import cycle, a layering violation (a module
of a lower layer naming one of a higher layer, see LAYERS) or a function longer than the limit.
Plain text only, no dependencies: CI runs it with the system python.
"""
import argparse
import os
import re
import sys

SRC = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "src")

# Lowest first. A module may name modules of its own layer and of lower layers only. The first
# matching prefix decides a module's layer.
LAYERS = [
    ("base", ["crate::sys", "crate::error", "crate::model", "crate::geom", "crate::rng"]),
    ("io", ["crate::io", "crate::tiling"]),
    ("algorithms", ["crate::ground", "crate::segment", "crate::label", "crate::stitch",
                    "crate::thin", "crate::synth", "crate::eval"]),
    ("stages", ["crate::budget", "crate::stages"]),
    ("config", ["crate::config"]),
    ("report", ["crate::report"]),
    ("run", ["crate::pipeline", "crate::region"]),
    ("front", ["crate::cli", "crate"]),
]

# Modules of the same layer that must not name each other (algorithms know nothing of each
# other's internals except through the base layer). Pairs (user, used) allowed explicitly.
ALGORITHMS_ALLOWED = {
    ("crate::label", "crate::ground"),     # labels read the ground TIN heights
    ("crate::label", "crate::segment"),    # labels work on segment features
    ("crate::eval", "crate::label"),       # eval scores label classes
    ("crate::eval", "crate::ground"),
    ("crate::eval", "crate::segment"),
    ("crate::eval", "crate::io"),
    ("crate::synth", "crate::label"),      # the generator writes truth in label classes
    ("crate::synth", "crate::io"),
    ("crate::stitch", "crate::io"),
}


def module_files():
    """(module path, file path) for every non-test source file."""
    out = {}
    for root, _dirs, files in os.walk(SRC):
        for f in files:
            if not f.endswith(".rs"):
                continue
            path = os.path.join(root, f)
            rel = os.path.relpath(path, SRC)[:-3].split(os.sep)
            if rel == ["lib"] or rel == ["main"]:
                mod = "crate" if rel == ["lib"] else "main"
            else:
                if rel[-1] == "mod":
                    rel = rel[:-1]
                mod = "crate::" + "::".join(rel)
            out[mod] = path
    return out


def strip_comments_and_strings(text):
    """Code only: comments removed, string and char literal contents blanked (a small lexer:
    line and nested block comments, "..." with escapes, r"..."/r#"..."# raw strings, b"..."
    byte strings, char literals told apart from lifetimes). Newlines are kept."""
    out = []
    i, n = 0, len(text)

    def ident_char(c):
        return c.isalnum() or c == "_"

    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        if text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append("\n" * text.count("\n", i, j))
            i = j
            continue
        prev_ident = i > 0 and ident_char(text[i - 1])
        m = None if prev_ident else re.match(r'b?r(#*)"', text[i:i + 300])
        if m:
            close = '"' + m.group(1)
            j = text.find(close, i + m.end())
            j = n if j < 0 else j + len(close)
            out.append('""' + "\n" * text.count("\n", i, j))
            i = j
            continue
        if c == '"' or (c == "b" and not prev_ident and text.startswith('b"', i)):
            j = i + (2 if c == "b" else 1)
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            out.append('""' + "\n" * text.count("\n", i, j))
            i = j + 1
            continue
        if c == "'":
            m = re.match(r"'(?:\\(?:x[0-9a-fA-F]{2}|u\{[0-9a-fA-F]+\}|.)|[^'\\\n])'", text[i:i + 16])
            if m:
                out.append("' '")
                i += m.end()
                continue
        out.append(c)
        i += 1
    return "".join(out)


def drop_test_code(text):
    """Remove `#[cfg(test)]`-gated items (modules, functions, uses)."""
    out = []
    i = 0
    pat = re.compile(r"#\[cfg\(test\)\]")
    while True:
        m = pat.search(text, i)
        if not m:
            out.append(text[i:])
            break
        out.append(text[i:m.start()])
        j = m.end()
        # the gated item ends at its matching brace or at the first ';' before any '{'
        k = j
        while k < len(text) and text[k] not in "{;":
            k += 1
        if k < len(text) and text[k] == ";":
            i = k + 1
            continue
        depth = 0
        while k < len(text):
            if text[k] == "{":
                depth += 1
            elif text[k] == "}":
                depth -= 1
                if depth == 0:
                    break
            k += 1
        i = k + 1
    return "".join(out)


def test_files(files):
    """Files declared as `#[cfg(test)] mod x;` are test code."""
    tests = set()
    for mod, path in files.items():
        text = strip_comments_and_strings(open(path, encoding="utf-8").read())
        for m in re.finditer(r"#\[cfg\(test\)\]\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+(\w+)\s*;", text):
            base = "crate" if mod in ("crate", "main") else mod
            tests.add(base + "::" + m.group(1))
    return tests


def split_use_tree(prefix, tree):
    """Expand `a::{b, c::{d, e}}` into full paths."""
    tree = tree.strip()
    m = re.match(r"^(.*?)\{(.*)\}$", tree, flags=re.S)
    if not m:
        full = (prefix + "::" + tree) if prefix else tree
        full = re.sub(r"\s+as\s+\w+$", "", full.strip())
        return [full.strip(":")]
    head = m.group(1).rstrip(":").strip()
    inner = m.group(2)
    parts, depth, cur = [], 0, ""
    for ch in inner:
        if ch == "{":
            depth += 1
        elif ch == "}":
            depth -= 1
        if ch == "," and depth == 0:
            parts.append(cur)
            cur = ""
        else:
            cur += ch
    if cur.strip():
        parts.append(cur)
    base = (prefix + "::" + head) if prefix and head else (head or prefix)
    out = []
    for p in parts:
        if p.strip() == "self":
            out.append(base)
        else:
            out.extend(split_use_tree(base, p))
    return out


def absolutise(path, mod, modules=None):
    """Turn a path used in `mod` into a `crate::` path: `crate::`, `self::`, `super::`, and
    (2018 edition) a path starting with a child module of `mod`. None for external crates."""
    segs = path.split("::")
    if segs[0] == "crate":
        return path
    if modules is not None and mod != "main":
        child = mod + "::" + segs[0]
        if child in modules:
            return "::".join([mod] + segs)
    cur = mod.split("::") if mod != "main" else ["crate"]
    if segs[0] == "self":
        return "::".join(cur + segs[1:])
    if segs[0] == "super":
        while segs and segs[0] == "super":
            cur = cur[:-1]
            segs = segs[1:]
        return "::".join(cur + segs)
    if segs[0] == "tessera" and mod == "main":
        return "::".join(["crate"] + segs[1:])
    return None


USE_RE = re.compile(r"(?<![\w:])(pub(?:\([^)]*\))?\s+)?\buse\s+([^;{}]+(?:\{[^;]*\})?[^;{}]*);")


def parse_module(mod, text, modules):
    """(uses, reexports) of one module: the crate paths it names, and `pub use` name -> path."""
    uses, reexports = [], {}
    for m in USE_RE.finditer(text):
        is_pub = bool(m.group(1))
        for p in split_use_tree("", m.group(2)):
            full = absolutise(p, mod, modules)
            if full is None:
                continue
            if p.endswith("*"):
                full = full[:-3] if full.endswith("::*") else full
                uses.append(full)
                if is_pub:
                    reexports.setdefault("*", []).append(full)
                continue
            uses.append(full)
            if is_pub:
                name = full.split("::")[-1]
                alias = re.search(r"\bas\s+(\w+)", m.group(2))
                reexports[name] = full
                if alias and len(split_use_tree("", m.group(2))) == 1:
                    reexports[alias.group(1)] = full
    code = USE_RE.sub(" ", text)
    for m in re.finditer(r"(?<![\w:])((?:crate|super|self)(?:::\w+)+)", code):
        full = absolutise(m.group(1), mod)
        if full:
            uses.append(full)
    # The binary's modules (main.rs, commands/) name the library as `tessera::`.
    for m in re.finditer(r"(?<![\w:])tessera((?:::\w+)+)", code):
        uses.append("crate" + m.group(1))
    return uses, reexports


ITEM_RE = re.compile(r"\b(?:fn|struct|enum|trait|type|const|static|union)\s+(\w+)|\bmod\s+(\w+)\s*\{")


def resolve(path, modules, reexports, defined, depth=0):
    """The module defining the item `path` names: re-exports (`pub use a::X`, and globs
    `pub use a::*` when `a` defines or re-exports the name) are followed to the definition."""
    segs = path.split("::")
    for n in range(len(segs), 0, -1):
        prefix = "::".join(segs[:n])
        if prefix in modules:
            rest = segs[n:]
            if rest and depth < 8:
                target = reexports.get(prefix, {}).get(rest[0])
                if target and target != path:
                    return resolve("::".join([target] + rest[1:]), modules, reexports, defined,
                                   depth + 1)
                if rest[0] not in defined.get(prefix, ()):
                    for g in reexports.get(prefix, {}).get("*", []):
                        if rest[0] in defined.get(g, ()) or rest[0] in reexports.get(g, {}):
                            return resolve("::".join([g] + rest), modules, reexports, defined,
                                           depth + 1)
            return prefix
    return None


def layer_of(mod):
    for i, (_name, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if mod == p or (p != "crate" and mod.startswith(p + "::")):
                return i
    return len(LAYERS) - 1


def top_algorithm(mod):
    for p in LAYERS[2][1]:
        if mod == p or mod.startswith(p + "::"):
            return p
    return None


def long_functions(path, limit):
    text = open(path, encoding="utf-8").read()
    lines = text.split("\n")
    clean = strip_comments_and_strings(text).split("\n") if False else None
    out = []
    fn_re = re.compile(r"^\s*(?:pub(?:\([^)]*\))?\s+)?(?:const\s+)?(?:unsafe\s+)?fn\s+(\w+)")
    i = 0
    while i < len(lines):
        m = fn_re.match(lines[i])
        if m:
            start = i
            depth, seen = 0, False
            j = i
            while j < len(lines):
                line = re.sub(r"//.*", "", lines[j])
                line = re.sub(r'"(?:\\.|[^"\\])*"', '""', line)
                line = re.sub(r"'(?:\\.|[^'\\])'", "' '", line)
                depth += line.count("{") - line.count("}")
                if "{" in line:
                    seen = True
                if seen and depth <= 0:
                    break
                if not seen and line.rstrip().endswith(";"):
                    break
                j += 1
            n = j - start + 1
            if n > limit:
                out.append((m.group(1), start + 1, n))
            i = start + 1
            continue
        i += 1
    return out


def find_cycles(graph):
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, sccs = {}, {}, [], set(), []
    counter = [0]
    sys.setrecursionlimit(10000)

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
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
            if len(comp) > 1:
                sccs.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sccs


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--check", action="store_true", help="exit 1 on any finding")
    ap.add_argument("--dot", help="write the module graph in Graphviz dot format")
    ap.add_argument("--max-fn-lines", type=int, default=150)
    args = ap.parse_args()

    files = module_files()
    tests = test_files(files)
    files = {m: p for m, p in files.items()
             if not any(m == t or m.startswith(t + "::") for t in tests)}
    texts, uses, reexports, defined = {}, {}, {}, {}
    for mod, path in files.items():
        text = drop_test_code(strip_comments_and_strings(open(path, encoding="utf-8").read()))
        texts[mod] = text
        uses[mod], reexports[mod] = parse_module(mod, text, set(files))
        defined[mod] = {a or b for a, b in ITEM_RE.findall(text)}
    modules = set(files)
    graph = {}
    for mod in modules:
        targets = set()
        for p in uses[mod]:
            t = resolve(p, modules, reexports, defined)
            if t and t != mod and t != "crate":
                targets.add(t)
        graph[mod] = targets

    findings = 0
    cycles = find_cycles(graph)
    for comp in cycles:
        findings += 1
        print("cycle: " + " <-> ".join(comp))
        for a in comp:
            for b in sorted(graph[a]):
                if b in comp:
                    print(f"    {a} -> {b}")
    for a in sorted(graph):
        if a == "main":
            continue
        for b in sorted(graph[a]):
            la, lb = layer_of(a), layer_of(b)
            if lb > la:
                findings += 1
                print(f"layering: {a} ({LAYERS[la][0]}) names {b} ({LAYERS[lb][0]})")
            elif la == lb == 2:
                ta, tb = top_algorithm(a), top_algorithm(b)
                if ta != tb and (ta, tb) not in ALGORITHMS_ALLOWED:
                    findings += 1
                    print(f"layering: algorithm {a} names algorithm {b}")
    for mod, path in sorted(files.items()):
        for name, line, n in long_functions(path, args.max_fn_lines):
            findings += 1
            print(f"long function: {os.path.relpath(path, os.path.join(SRC, '..'))}:{line} "
                  f"{name} {n} lines (limit {args.max_fn_lines})")
    if args.dot:
        with open(args.dot, "w") as f:
            f.write("digraph tessera {\n  rankdir=LR;\n")
            for a in sorted(graph):
                for b in sorted(graph[a]):
                    f.write(f'  "{a}" -> "{b}";\n')
            f.write("}\n")
    edges = sum(len(v) for v in graph.values())
    print(f"{len(modules)} modules, {edges} use edges, {len(cycles)} cycles, {findings} findings")
    if args.check and findings:
        sys.exit(1)


if __name__ == "__main__":
    main()
