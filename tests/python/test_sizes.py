"""tools/layers/sizes.py (scripts/check-layers.sh): a file over 550 lines
outside its tests, or a crate over a quarter of the Rust lines, is named;
test code does not count."""
import importlib.util
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("sizes", REPO / "tools" / "layers" / "sizes.py")
sizes = importlib.util.module_from_spec(spec)
spec.loader.exec_module(sizes)


def lines(n: int) -> str:
    return "".join(f"// {i}\n" for i in range(n))


def check(capsys, root):
    code = sizes.main(["--root", str(root)])
    return code, capsys.readouterr().out


def test_a_long_file_and_a_heavy_crate_are_named(tmp_path, capsys):
    for crate in "abcde":
        (tmp_path / crate / "src").mkdir(parents=True)
        (tmp_path / crate / "src" / "lib.rs").write_text(lines(100))
    (tmp_path / "a" / "src" / "big.rs").write_text(lines(551))
    code, out = check(capsys, tmp_path)
    assert code == 1
    assert "big.rs: 551 lines outside tests" in out
    assert "crate a: 651 of the workspace's 1051" in out
    assert "crate b" not in out


def test_tests_do_not_count(tmp_path, capsys):
    for crate in "abcde":
        (tmp_path / crate / "src").mkdir(parents=True)
        (tmp_path / crate / "src" / "lib.rs").write_text(lines(100))
    (tmp_path / "a" / "src" / "long.rs").write_text(lines(10) + "#[cfg(test)]\nmod tests {\n" + lines(900) + "}\n")
    (tmp_path / "a" / "src" / "long_tests.rs").write_text(lines(900))
    (tmp_path / "a" / "src" / "tests").mkdir()
    (tmp_path / "a" / "src" / "tests" / "more.rs").write_text(lines(900))
    code, out = check(capsys, tmp_path)
    assert (code, out) == (0, "")


def test_a_test_only_use_line_does_not_end_the_count(tmp_path, capsys):
    src = tmp_path / "a" / "src"
    src.mkdir(parents=True)
    (src / "lib.rs").write_text("#[cfg(test)]\nuse x::y;\n" + lines(600) + "#[cfg(test)]\n#[path = \"t.rs\"]\nmod tests;\n")
    code, out = check(capsys, tmp_path)
    assert code == 1 and "lib.rs: 602 lines outside tests" in out, out
