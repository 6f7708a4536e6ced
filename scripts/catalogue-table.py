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
protocol = re.findall(r'\(\s*"(protocol: [^"]+)",\s*.*?,\s*"((?:[^"\\]|\\.)*)",?\s*\),\n', src, re.S)
print("| # | Input | Command line (`{dir}`: the prepared files) | The one error line holds |")
print("|---|---|---|---|")
n = 0
for name, args, needle in rows:
    n += 1
    args = " ".join(re.findall(r'"((?:[^"\\]|\\.)*)"', args))
    print(f"| {n} | {name} | `{args}` | `{needle}` |")
for name, needle in protocol:
    n += 1
    print(f"| {n} | {name} | the service's hello or header check | `{needle}` |")
