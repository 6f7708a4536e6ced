"""Reading Rust source without a compiler, for the checkers of tools/layers
(import_cycles.py, sizes.py, string_errors.py, flag_names.py): which code
is test code (files named `tests.rs` or `*_tests.rs`, anything under a
`tests/` directory, a file from its first `#[cfg(test)]` module on, items
under `#[cfg(test)]`), a file's module path, and the tokens of a file with
its comments and literals blanked, with the walks over them (bracket
groups, attributes, items, `use` trees).

Standard library only.
"""
import bisect
import re
from pathlib import Path


# A test module: `#[cfg(test)]` (maybe with more attributes) on a `mod`. A
# `#[cfg(test)] use` line above it does not start the tests.
TEST_MODULE = re.compile(r"^[ \t]*#\[cfg\((?:all\()?test\b[^\n]*\n(?:[ \t]*#\[[^\n]*\n)*[ \t]*(?:pub(?:\([^)]*\))? )?mod ",
                         re.M)


def without_tests(text: str) -> str:
    """`text` up to its first `#[cfg(test)]` module (tests sit at a file's end)."""
    m = TEST_MODULE.search(text)
    return text if m is None else text[:m.start()]


def is_test_file(rel: Path) -> bool:
    """`rel` relative to the crate's src/."""
    return (rel.name == "tests.rs" or rel.name.endswith("_tests.rs")
            or "tests" in rel.parts[:-1])


def module_of(rel: Path) -> tuple:
    """The module path of a file relative to src/: lib.rs → (), a/b.rs and
    a/b/mod.rs → ("a", "b")."""
    parts = list(rel.with_suffix("").parts)
    if parts == ["lib"] or parts == ["main"]:
        return ()
    if parts[-1] == "mod":
        parts.pop()
    return tuple(parts)


def blank_literals(text: str) -> str:
    """`text` with comments, strings and char literals replaced by spaces
    (newlines kept, so lines still count)."""
    out = list(text)
    n, i = len(text), 0

    def blank(a, b):
        for k in range(a, b):
            if out[k] != "\n":
                out[k] = " "

    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            blank(i, j)
            i = j
        elif text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            blank(i, j)
            i = j
        elif c in "rbc" and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")) \
                and (m := re.match(r'(?:br|cr|r)(#*)"', text[i:i + 260])):
            close = '"' + m.group(1)
            j = text.find(close, i + m.end())
            j = n if j < 0 else j + len(close)
            blank(i, j)
            i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            blank(i, j + 1)
            i = j + 1
        elif c == "'":
            # A char literal ('x', '\n', '\u{…}'), else a lifetime or label.
            if i + 1 < n and text[i + 1] == "\\":
                j = text.find("'", i + 3)
                j = n if j < 0 else j
                blank(i, j + 1)
                i = j + 1
            elif i + 2 < n and text[i + 2] == "'":
                blank(i, i + 3)
                i += 3
            else:
                i += 1
        else:
            i += 1
    return "".join(out)


TOKEN = re.compile(r"\$?[A-Za-z_][A-Za-z0-9_]*|::|\S")
OPEN, CLOSE = "([{", ")]}"
ITEM_KEYWORDS = {"fn", "mod", "impl", "struct", "enum", "trait", "union", "extern", "unsafe",
                 "async", "const", "static", "type", "use", "macro_rules", "pub", "default"}


def tokens_of(text: str):
    """[(token, line)] of the source with literals and comments blanked."""
    clean = blank_literals(text)
    starts = [0] + [m.end() for m in re.finditer("\n", clean)]
    return [(m.group(), bisect.bisect_right(starts, m.start())) for m in TOKEN.finditer(clean)]


def matching(toks, i):
    """Index just past the bracket group opening at toks[i]."""
    depth = 0
    for j in range(i, len(toks)):
        t = toks[j][0]
        if t in OPEN:
            depth += 1
        elif t in CLOSE:
            depth -= 1
            if depth == 0:
                return j + 1
    return len(toks)


def attribute_end(toks, i):
    """toks[i] is `#`: (index past the attribute, its tokens) or None."""
    j = i + 1
    if j < len(toks) and toks[j][0] == "!":
        j += 1
    if j < len(toks) and toks[j][0] == "[":
        end = matching(toks, j)
        return end, [t for t, _ in toks[j + 1:end - 1]]
    return None


def is_cfg_test(attr) -> bool:
    """`cfg(test)` or `cfg(all(test, …))`: code that only tests build."""
    return attr[:4] == ["cfg", "(", "test", ")"] or attr[:6] == ["cfg", "(", "all", "(", "test", ","] \
        or attr[:6] == ["cfg", "(", "all", "(", "test", ")"]


def skip_item(toks, i):
    """Index past the item (or field, statement, arm) starting at toks[i],
    with its own attributes; also the name of a `mod NAME;` it declares."""
    while i < len(toks) and toks[i][0] == "#":
        a = attribute_end(toks, i)
        if a is None:
            break
        i = a[0]
    first = toks[i][0] if i < len(toks) else ""
    item = first in ITEM_KEYWORDS
    declared = None
    j = i
    while j < len(toks):
        t = toks[j][0]
        if t in CLOSE:
            return j, declared  # the end of the enclosing group
        if t == ";":
            return j + 1, declared
        if t == "," and not item:
            return j + 1, declared
        if t == "mod" and j + 2 < len(toks) and toks[j + 2][0] == ";":
            declared = toks[j + 1][0]
        if t == "{" and (item and first not in ("const", "static", "type", "use") or not item):
            return matching(toks, j), declared
        if t in OPEN:
            j = matching(toks, j)
            continue
        j += 1
    return j, declared


def parse_use(toks, i):
    """toks[i] follows `use`: ([(segments, glob, line)], index past the `;`)."""
    paths = []

    def tree(j, prefix):
        segs = list(prefix)
        line = toks[j][1] if j < len(toks) else 0
        if j < len(toks) and toks[j][0] == "::":
            segs.append("::")
            j += 1
        while j < len(toks):
            t, line = toks[j]
            if t == "{":
                j += 1
                while j < len(toks) and toks[j][0] != "}":
                    j = tree(j, segs)
                    if j < len(toks) and toks[j][0] == ",":
                        j += 1
                return j + 1
            if t == "*":
                paths.append((segs, True, line))
                return j + 1
            if re.fullmatch(r"\$?\w+", t):
                segs = segs + [t]
                j += 1
                if j < len(toks) and toks[j][0] == "as":
                    j += 2
                if j < len(toks) and toks[j][0] == "::":
                    j += 1
                    continue
                if segs and segs[-1] == "self":
                    segs = segs[:-1]
                paths.append((segs, False, line))
                return j
            return j  # something else: stop
        return j

    j = tree(i, [])
    while j < len(toks) and toks[j][0] != ";":
        j += 1
    return paths, j + 1
