#!/usr/bin/env python3
"""No import loops (issue 32; scripts/check-layers.sh runs it): exit 0 when
neither the Rust library crates nor the trainer package import in a circle,
1 naming every cycle, its modules and one import line (file:line) per edge.

Rust, each library crate of layer_check.RUST_CRATES (under runtime/)
(not the binary, runtime/cli): a module is a file, `foo.rs` (or
`foo/mod.rs`) the parent of the files in `foo/`. A file references the
modules named by the paths of its `use` statements and of its code:
`crate::a::b…`, `super::…`, `self::…`, bare `a::b` in a `use` when `a` is a
child module, and bare `a::b` in code when `a` is a child of a module
glob-imported (`use super::*`). Test code does not count: files named
`tests.rs` or `*_tests.rs`, anything under a `tests/` directory, and items
under `#[cfg(test)]` (inline `mod tests { … }` blocks, `mod x;` declarations,
single items). A child using its parent's items and a parent calling its
child is ordinary Rust; what is a loop is between siblings: for every module,
child A → child B when any file of A's subtree references anything in B's,
and each strongly connected component of more than one child is a cycle.
Re-exports are not followed: `crate::Thing` is a reference to the crate root
whatever module defines `Thing`.

Python, the trainer package models/nedrt_train: the modules are its files,
the edges `from .x import …`, `from . import x`, `from nedrt_train.x import
…`, `import nedrt_train.x`, at any depth (an import inside a function is a
dependency all the same); each strongly connected component of more than
one module is a cycle.

    python3 tools/layers/import_cycles.py                # the repository
    python3 tools/layers/import_cycles.py --rust DIR --python DIR   # those only

The reading of Rust source (test code, tokens, `use` trees) is in
rust_source.py, what the checkers share (the repository, the crates, a
per-crate command line) in layer_check.py; this file builds the module
graphs and finds their cycles. Standard library only.
"""
import argparse
import ast
import re
import sys
from pathlib import Path

# The modules beside this file, however it is loaded (script or test).
sys.path.insert(0, str(Path(__file__).resolve().parent))

from layer_check import REPO, RUST_CRATES, display  # noqa: E402
from rust_source import (  # noqa: E402
    attribute_end, is_cfg_test, is_test_file, module_of, parse_use, skip_item, tokens_of,
)
# Names the other checkers imported from here before rust_source.py and
# layer_check.py held them; still importable from here.
from layer_check import crate_check_main  # noqa: E402,F401
from rust_source import CLOSE, ITEM_KEYWORDS, OPEN, TEST_MODULE, TOKEN  # noqa: E402,F401
from rust_source import blank_literals, matching, without_tests  # noqa: E402,F401

PYTHON_PACKAGE = "models/nedrt_train"


# ---------------------------------------------------------------- graphs


def strongly_connected(nodes, edges):
    """Tarjan's components of the graph `edges` (node → set of nodes), each
    sorted, in a stable order; only those of more than one node."""
    index, low, on_stack, stack, out = {}, {}, set(), [], []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(nodes):
        if v not in index:
            visit(v)
    return sorted(out)


# ------------------------------------------------------------------ Rust


class RustCrate:
    def __init__(self, src: Path, shown: Path):
        self.src, self.shown = src, shown
        self.name = self.crate_name()
        files = {}
        for path in sorted(src.rglob("*.rs")):
            rel = path.relative_to(src)
            if is_test_file(rel):
                continue
            files[module_of(rel)] = path
        self.files = files
        self.children = {m: set() for m in files}
        for m in files:
            if m:
                self.children.setdefault(m[:-1], set()).add(m[-1])
        # module → [(target module, line, text)]
        self.refs = {}
        excluded = set()
        for m in sorted(files, key=len):
            if any(m[:k] in excluded for k in range(len(m) + 1)):
                excluded.add(m)
                continue
            self.refs[m], test_children = self.references(m)
            excluded |= {m + (c,) for c in test_children}
        self.modules = [m for m in files if m not in excluded]

    def crate_name(self) -> str:
        toml = self.src.parent / "Cargo.toml"
        if toml.is_file():
            m = re.search(r'^\s*name\s*=\s*"([^"]+)"', toml.read_text(), re.M)
            if m:
                return m.group(1)
        return self.src.parent.name

    def node(self, path):
        """The file module holding the absolute path `path` (its longest
        prefix that is a file)."""
        path = tuple(path)
        while path and path not in self.files:
            path = path[:-1]
        return path

    def resolve(self, here, segs):
        """Absolute module path of `segs` written in module `here`, or None
        (another crate)."""
        if not segs:
            return None
        head, rest = segs[0], segs[1:]
        if head in ("crate", "$crate"):
            base = []
        elif head in ("self", "super"):
            base = list(here)
            if head == "super":
                if not base:
                    return None
                base.pop()
        elif head == "::":
            return None
        elif head in self.children.get(self.node(here), ()) and self.node(here) == tuple(here):
            return tuple(here) + tuple(segs)
        else:
            return None
        for s in rest:
            if s == "super" and base:
                base.pop()
            elif s == "self":
                continue
            else:
                base.append(s)
        return tuple(base)

    def references(self, module):
        path = self.files[module]
        lines = path.read_text(errors="replace").splitlines()
        toks = tokens_of(path.read_text(errors="replace"))
        refs, test_children, globs = [], set(), []
        inline = []  # (name, depth at which it closes)
        depth = 0

        def here():
            return module + tuple(n for n, _ in inline)

        def add(target, line):
            if target is not None:
                refs.append((self.node(target), line, lines[line - 1].strip() if line <= len(lines) else ""))

        i = 0
        while i < len(toks):
            t, line = toks[i]
            if t == "#":
                a = attribute_end(toks, i)
                if a is not None:
                    end, attr = a
                    if is_cfg_test(attr):
                        if toks[i + 1][0] == "!":  # #![cfg(test)]: the whole file
                            return [], set()
                        i, declared = skip_item(toks, end)
                        if declared:
                            test_children.add(declared)
                        continue
                    i = end
                    continue
            if t == "mod" and i + 2 < len(toks) and toks[i + 2][0] == "{":
                inline.append((toks[i + 1][0], depth))
                depth += 1
                i += 3
                continue
            if t == "{":
                depth += 1
            elif t == "}":
                depth -= 1
                if inline and inline[-1][1] == depth:
                    inline.pop()
            if t == "use":
                paths, i = parse_use(toks, i + 1)
                for segs, glob, at in paths:
                    target = self.resolve(here(), segs)
                    add(target, at)
                    if glob and target is not None and target in self.files:
                        globs.append(target)
                continue
            previous = toks[i - 1][0] if i else ""
            if previous in ("::", ".") or i + 1 >= len(toks) or toks[i + 1][0] != "::" \
                    or not re.fullmatch(r"\$?\w+", t):
                i += 1
                continue
            segs, j = [t], i + 1
            while j + 1 < len(toks) and toks[j][0] == "::" and re.fullmatch(r"\$?\w+", toks[j + 1][0]):
                segs.append(toks[j + 1][0])
                j += 2
            if t in ("crate", "$crate", "self", "super"):
                add(self.resolve(here(), segs), line)
            else:
                for g in globs:
                    if t in self.children.get(g, ()):
                        add(g + tuple(segs), line)
            i = j
        return refs, test_children

    def cycles(self):
        """[(parent module, [children], [(a, b, file, line, text)])]."""
        live = set(self.modules)
        # parent → child → child → first evidence
        graphs = {}
        for m in sorted(self.modules):
            for target, line, text in self.refs.get(m, ()):
                if target not in live:
                    continue
                k = 0
                while k < min(len(m), len(target)) and m[k] == target[k]:
                    k += 1
                if k == len(m) or k == len(target):
                    continue  # one is the other's ancestor
                parent, a, b = m[:k], m[k], target[k]
                edge = graphs.setdefault(parent, {}).setdefault(a, {})
                edge.setdefault(b, (self.files[m], line, text))
        out = []
        for parent in sorted(graphs):
            g = graphs[parent]
            nodes = set(g) | {b for e in g.values() for b in e}
            for comp in strongly_connected(nodes, {a: set(e) for a, e in g.items()}):
                evidence = [(a, b) + g[a][b] for a in comp for b in sorted(g.get(a, ())) if b in comp]
                out.append((parent, comp, evidence))
        return out

    def report(self, root: Path):
        lines = []
        for parent, comp, evidence in self.cycles():
            where = "the crate root" if not parent else "::".join(parent)
            shown = ["::".join(parent + (c,)) for c in comp]
            lines.append(f"import cycle in Rust crate {self.name} ({self.shown}), among the children of "
                         f"{where}: {', '.join(shown)}")
            for a, b, path, line, text in evidence:
                lines.append(f"  {'::'.join(parent + (a,))} -> {'::'.join(parent + (b,))}: "
                             f"{display(path, root)}:{line}: {text}")
        return lines


# ---------------------------------------------------------------- Python


class PythonPackage:
    def __init__(self, directory: Path, shown: Path):
        self.dir, self.shown = directory, shown
        self.name = directory.name
        self.files = {}
        for path in sorted(directory.rglob("*.py")):
            parts = path.relative_to(directory).with_suffix("").parts
            if "__pycache__" in parts:
                continue
            self.files[".".join(parts)] = path
        self.edges = {m: {} for m in self.files}
        for m, path in self.files.items():
            tree = ast.parse(path.read_text(errors="replace"), str(path))
            lines = path.read_text(errors="replace").splitlines()
            for node in ast.walk(tree):
                for target in self.targets(m, node):
                    if target in self.files and target != m:
                        self.edges[m].setdefault(target, (path, node.lineno, lines[node.lineno - 1].strip()))

    def module(self, dotted):
        """The package module `dotted` (relative to the package) names, or its
        package's `__init__`."""
        while dotted and dotted not in self.files:
            dotted = dotted.rpartition(".")[0]
        return dotted or "__init__"

    def targets(self, here, node):
        package = here.split(".")[:-1]  # the module's package, relative (`__init__`'s too)
        if isinstance(node, ast.ImportFrom):
            if node.level:
                if node.level - 1 > len(package):
                    return []
                base = package[:len(package) - (node.level - 1)]
            elif node.module and (node.module == self.name or node.module.startswith(self.name + ".")):
                base = []
                node_module = node.module[len(self.name) + 1:] if node.module != self.name else ""
                return self.from_targets(base, node_module, node)
            else:
                return []
            return self.from_targets(base, node.module or "", node)
        if isinstance(node, ast.Import):
            out = []
            for alias in node.names:
                if alias.name.startswith(self.name + "."):
                    out.append(self.module(alias.name[len(self.name) + 1:]))
            return out
        return []

    def from_targets(self, base, module, node):
        prefix = ".".join(base + ([module] if module else []))
        out = []
        for alias in node.names:
            name = f"{prefix}.{alias.name}" if prefix else alias.name
            if name in self.files:
                out.append(name)  # from . import x: the module x
            else:
                out.append(self.module(prefix) if prefix else "__init__")
        return out

    def report(self, root: Path):
        lines = []
        for comp in strongly_connected(self.files, {m: set(e) for m, e in self.edges.items()}):
            lines.append(f"import cycle in the Python package {self.name} ({self.shown}): {', '.join(comp)}")
            for a in comp:
                for b in sorted(self.edges[a]):
                    if b in comp:
                        path, line, text = self.edges[a][b]
                        lines.append(f"  {a} -> {b}: {display(path, root)}:{line}: {text}")
        return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--root", type=Path, default=REPO,
                        help="repository whose crates and trainer to check (default: this one)")
    parser.add_argument("--rust", type=Path, action="append", default=[], metavar="SRC",
                        help="a crate's src/ directory to check instead (repeatable)")
    parser.add_argument("--python", type=Path, action="append", default=[], metavar="PACKAGE",
                        help="a Python package directory to check instead (repeatable)")
    args = parser.parse_args(argv)
    root = args.root
    if args.rust or args.python:
        rust, python = args.rust, args.python
    else:
        rust = [root / "runtime" / c / "src" for c in RUST_CRATES]
        python = [root / PYTHON_PACKAGE]
    missing = [p for p in rust + python if not p.is_dir()]
    if missing:
        for p in missing:
            print(f"import cycles: {p} is not a directory", file=sys.stderr)
        return 2
    lines, files = [], 0
    for src in rust:
        crate = RustCrate(src, Path(display(src, root)))
        files += len(crate.modules)
        lines += crate.report(root)
    modules = 0
    for package in python:
        pkg = PythonPackage(package, Path(display(package, root)))
        modules += len(pkg.files)
        lines += pkg.report(root)
    if lines:
        print("\n".join(lines))
        return 1
    print(f"import cycles: none among the modules of {len(rust)} Rust crate(s) ({files} files, test code "
          f"excluded) nor of {len(python)} Python package(s) ({modules} modules)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
