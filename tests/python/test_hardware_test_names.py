"""scripts/test.sh runs the tests that need a part (a GPU adapter, ONNX
Runtime, an X display, ...) by name, `cargo test -- --ignored needs_`: a
test marked `#[ignore = "needs ..."]` outside a module named `needs_…`
(and without `needs_` in its own name) is never run by CI. Four such
tests were found on 2026-11-30; this keeps it from happening again."""
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
MOD = re.compile(r"^(\s*)(?:pub(?:\([^)]*\))?\s+)?mod\s+(\w+)\s*\{")
FN = re.compile(r"^\s*(?:pub(?:\([^)]*\))?\s+)?fn\s+(\w+)")


def unreachable(text: str) -> list:
    """(line, test) of each `#[ignore = "needs` test that the name filter
    `needs_` misses: the enclosing modules are found by indentation
    (rustfmt's)."""
    lines = text.splitlines()
    out = []
    for i, line in enumerate(lines):
        if not line.lstrip().startswith('#[ignore = "needs'):
            continue
        name = next((m.group(1) for l in lines[i + 1:i + 4] if (m := FN.match(l))), "?")
        depth = len(line) - len(line.lstrip())
        path = [name]
        for l in reversed(lines[:i]):
            m = MOD.match(l)
            if m and len(m.group(1)) < depth:
                path.append(m.group(2))
                depth = len(m.group(1))
        if not any("needs_" in p for p in path):
            out.append((i + 1, "::".join(reversed(path))))
    return out


def test_the_check_finds_a_test_outside_a_needs_module():
    text = (
        "mod tests {\n    #[test]\n    #[ignore = \"needs a GPU adapter\"]\n    fn lost() {}\n\n"
        "    mod needs_gpu {\n        use super::*;\n\n        #[test]\n"
        "        #[ignore = \"needs a GPU adapter\"]\n        fn found() {}\n    }\n}\n\n"
        "#[test]\n#[ignore = \"needs ONNX Runtime\"]\nfn needs_ort_by_name() {}\n"
        "#[test]\n#[ignore = \"needs ONNX Runtime\"]\nfn top_level() {}\n"
    )
    assert unreachable(text) == [(3, "tests::lost"), (19, "top_level")]


def test_every_hardware_test_in_the_repository_is_reached_by_the_name_filter():
    missed = []
    for path in sorted(REPO.glob("runtime/**/*.rs")) + sorted(REPO.glob("tests/**/*.rs")):
        if "target" in path.parts:
            continue
        missed += [f"{path.relative_to(REPO)}:{line}: {name}"
                   for line, name in unreachable(path.read_text())]
    assert not missed, "\n".join(missed)
