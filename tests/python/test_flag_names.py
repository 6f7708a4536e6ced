"""tools/layers/flag_names.py (scripts/check-layers.sh): on synthetic crates
written to tmp_path, a string literal naming a command-line flag is reported
(exit 1, file:line and the flag) while comments, attributes, test code and
words with inner dashes are not; and the repository's library crates name
none."""
import importlib.util
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "tools" / "layers" / "flag_names.py"
spec = importlib.util.spec_from_file_location("flag_names", SCRIPT)
flag_names = importlib.util.module_from_spec(spec)
spec.loader.exec_module(flag_names)


def write(root: Path, files: dict) -> Path:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def check(capsys, *args):
    code = flag_names.main([str(a) for a in args])
    return code, capsys.readouterr().out


def test_flags_in_plain_multiline_and_raw_literals_are_named(tmp_path, capsys):
    src = write(tmp_path / "src", {
        "lib.rs": "pub mod sink;\n",
        "sink.rs": (
            "fn a() -> String {\n"
            "    format!(\"no display; use {}\", \"--sink headless\")\n"
            "}\n"
            "fn b() -> &'static str {\n"
            "    \"a frame too large \\\n"
            "     (try --precision f16)\"\n"
            "}\n"
            "fn c() -> &'static str { let _q = '\"'; r#\"give \"--shm-dir\" a folder\"# }\n"
        ),
    })
    code, out = check(capsys, "--rust", src)
    assert code == 1
    assert "sink.rs:2: --sink in" in out
    assert "sink.rs:5: --precision in" in out
    assert "sink.rs:8: --shm-dir in" in out


def test_comments_attributes_tests_and_dashed_words_pass(tmp_path, capsys):
    src = write(tmp_path / "src", {
        "lib.rs": (
            "//! Run `nedrt run --sink record` to record.\n"
            "/* --backend cpu */\n"
            "/// Says --precision f16.\n"
            "pub fn f() -> &'static str { \"near-eye, read-back, 1e--3, a -- b, x--y\" }\n"
            "#[cfg(test)]\nmod tests {\n    fn t() { let _ = \"--sink record\"; }\n}\n"
        ),
        "gpu.rs": (
            "#[ignore = \"needs a GPU (cargo test -- --include-ignored)\"]\n"
            "pub fn g() {}\n"
        ),
        "tests.rs": "fn t() { let _ = \"--backend cpu\"; }\n",
    })
    code, out = check(capsys, "--rust", src)
    assert code == 0, out
    assert "no string literal of 1 library crate(s)" in out


def test_the_repository_library_crates_name_no_flag(capsys):
    code, out = check(capsys)
    assert code == 0, out
