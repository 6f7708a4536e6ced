#!/usr/bin/env python3
"""No string errors in a library's interface (issue 32; scripts/check-layers.sh
runs it): exit 0 when no Rust library crate (layer_check.RUST_CRATES, under
runtime/) has a `pub fn` (not `pub(crate)`, `pub(super)`, …) whose
return type is `Result<…, String>`, nor a trait whose method returns one;
1 naming each (file:line, the function and its return type).

A caller can match on a typed error and follow its source; a string it can
only print. `impl FromStr` is not caught (its `Err` is an associated type,
and its `from_str` no `pub fn`): a parse error of one argument may be a
string. Test code does not count: files named `tests.rs` or `*_tests.rs`,
anything under a `tests/` directory, and everything from a file's first
`#[cfg(test)]` module on (a `#[cfg(test)] use` line above it does not end
the check).

    python3 tools/layers/string_errors.py            # the repository
    python3 tools/layers/string_errors.py --rust DIR # those crates' src/ only

Standard library only.
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from layer_check import RUST_CRATES, crate_check_main, display  # noqa: E402
from rust_source import is_test_file, tokens_of, without_tests  # noqa: E402

QUALIFIERS = {"const", "async", "unsafe", "extern", "default"}
STRING = {"String", "std::string::String", "alloc::string::String"}
def split_top(tokens, sep=","):
    """`tokens` split at `sep` outside brackets (`->` is no bracket)."""
    parts, depth, cur = [], 0, []
    for k, t in enumerate(tokens):
        if t in "(<[":
            depth += 1
        elif t in ")]" or (t == ">" and not (k and tokens[k - 1] == "-")):
            depth -= 1
        if t == sep and depth == 0:
            parts.append(cur)
            cur = []
        else:
            cur.append(t)
    parts.append(cur)
    return parts


def is_string_result(ret) -> bool:
    """Whether the return type's tokens are `Result<T, String>`."""
    text = "".join(ret)
    for prefix in ("std::result::", "core::result::"):
        if text.startswith(prefix):
            ret = ret[2 * prefix.count("::"):]
            break
    if len(ret) < 4 or ret[0] != "Result" or ret[1] != "<" or ret[-1] != ">":
        return False
    args = split_top(ret[2:-1])
    return len(args) == 2 and "".join(args[1]) in STRING


def signature(toks, i):
    """For `fn` at toks[i]: (name, return-type tokens or None)."""
    n = len(toks)
    name = toks[i + 1][0] if i + 1 < n else "?"
    j = i + 2
    if j < n and toks[j][0] == "<":  # generics
        depth = 0
        while j < n:
            t = toks[j][0]
            if t == "<":
                depth += 1
            elif t == ">" and toks[j - 1][0] != "-":
                depth -= 1
                if depth == 0:
                    j += 1
                    break
            j += 1
    if j >= n or toks[j][0] != "(":
        return name, None
    depth = 0
    while j < n:  # the parameters
        t = toks[j][0]
        if t in "([{":
            depth += 1
        elif t in ")]}":
            depth -= 1
            if depth == 0:
                j += 1
                break
        j += 1
    if not (j + 1 < n and toks[j][0] == "-" and toks[j + 1][0] == ">"):
        return name, None
    j += 2
    ret, depth = [], 0
    while j < n:
        t = toks[j][0]
        if depth == 0 and t in ("{", ";", "where"):
            break
        if t in "(<[":
            depth += 1
        elif t in ")]" or (t == ">" and toks[j - 1][0] != "-"):
            depth -= 1
        ret.append(t)
        j += 1
    return name, ret


def trait_bodies(toks):
    """[(trait name, first token, last token)] of the trait declarations."""
    out = []
    for i, (t, _) in enumerate(toks):
        if t != "trait" or i + 1 >= len(toks):
            continue
        j = i + 1
        while j < len(toks) and toks[j][0] not in ("{", ";"):
            j += 1
        if j >= len(toks) or toks[j][0] == ";":
            continue
        depth, k = 0, j
        while k < len(toks):
            if toks[k][0] == "{":
                depth += 1
            elif toks[k][0] == "}":
                depth -= 1
                if depth == 0:
                    break
            k += 1
        out.append((toks[i + 1][0], j, k))
    return out


def is_pub(toks, i) -> bool:
    """Whether the `fn` at toks[i] is plain `pub` (not `pub(crate)` …)."""
    j = i - 1
    while j >= 0 and toks[j][0] in QUALIFIERS:
        j -= 1
    return j >= 0 and toks[j][0] == "pub"


def violations(path: Path, shown: str, text: str):
    """Lines naming each `pub fn` and trait method of `text` that returns
    `Result<…, String>`."""
    toks = tokens_of(without_tests(text))
    traits = trait_bodies(toks)
    out = []
    for i, (t, line) in enumerate(toks):
        if t != "fn":
            continue
        trait = next((name for name, a, b in traits if a < i < b), None)
        if trait is None and not is_pub(toks, i):
            continue
        name, ret = signature(toks, i)
        if ret is None or not is_string_result(ret):
            continue
        what = f"trait {trait}'s fn {name}" if trait else f"pub fn {name}"
        out.append(f"{shown}:{line}: {what} returns {''.join(ret).replace(',', ', ')}")
    return out


def check_crate(src: Path, root: Path):
    """(violation lines, files checked) of a crate's src/."""
    lines, files = [], 0
    for path in sorted(src.rglob("*.rs")):
        if is_test_file(path.relative_to(src)):
            continue
        files += 1
        lines += violations(path, display(path, root), path.read_text(encoding="utf-8"))
    return lines, files


def main(argv=None) -> int:
    return crate_check_main(
        argv, __doc__, "string errors", RUST_CRATES, check_crate,
        "a library's public function or trait method returns Result<_, String> "
        "(give it a typed error):",
        lambda crates, files: f"string errors: no public function nor trait method of {crates} "
        f"Rust crate(s) returns Result<_, String> ({files} files, test code excluded)")


if __name__ == "__main__":
    sys.exit(main())
