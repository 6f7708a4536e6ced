#!/usr/bin/env python3
"""Prints the bad-input catalogue of tests/cli/bad_input.rs as the
markdown table in docs/reliability.md (the test checks every row's name
is listed there):  python3 scripts/catalogue-table.py"""
import re
import pathlib

src = (pathlib.Path(__file__).parent.parent / "tests/cli/bad_input.rs").read_text()
rows = re.findall(
    r'row\(\s*"([^"]+)",\s*&\[(.*?)\],\s*"((?:[^"\\]|\\.)*)",?\s*\)', src, re.S
)
protocol = re.findall(r'\(\s*"(protocol(?: v2)?: [^"]+)",\s*.*?,\s*"((?:[^"\\]|\\.)*)",?\s*\),\n', src, re.S)
print("| # | Input | Command line (`{dir}`: the prepared files) | The one error line holds |")
print("|---|---|---|---|")
n = 0
for name, args, needle in rows:
    n += 1
    args = " ".join(re.findall(r'"((?:[^"\\]|\\.)*)"', args))
    print(f"| {n} | {name} | `{args}` | `{needle}` |")
for name, needle in protocol:
    n += 1
    if not name.startswith("protocol v2:"):
        check = "the service's hello or header check"
    elif needle in ("is not inside the 64×48 view", "premultiplied colour is at most its alpha"):
        check = "the compositor's layer check"
    else:
        check = "the service's version 2 header check"
    print(f"| {n} | {name} | {check} | `{needle}` |")
