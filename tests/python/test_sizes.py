"""tools/layers/sizes.py (scripts/check-layers.sh): a file over 550 lines
outside its tests, or a crate over a quarter of the Rust lines, is named;
so is a Python source file over 550 lines; test code does not count."""
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


def test_examples_harnesses_and_build_scripts_are_sized_too(tmp_path, capsys):
    for rel in ["runtime/openxr/examples/client.rs", "bench/burn/src/main.rs", "examples/soak.rs",
                "bench/burn/build.rs"]:
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(lines(551))
    (tmp_path / "examples" / "short.rs").write_text(lines(550))
    # The crates' own sources are the crate check's; tests and build outputs do not count.
    for rel in ["runtime/core/src/big.rs", "tests/cli/long.rs", "target/release/build/gen.rs",
                "bench/burn/src/main_tests.rs"]:
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(lines(900))
    code, out = sizes.main(["--rust-rest", str(tmp_path)]), capsys.readouterr().out
    assert code == 1
    assert out.splitlines() == [
        f"{Path('bench/burn/build.rs')}: 551 lines outside tests (at most 550)",
        f"{Path('bench/burn/src/main.rs')}: 551 lines outside tests (at most 550)",
        f"{Path('examples/soak.rs')}: 551 lines outside tests (at most 550)",
        f"{Path('runtime/openxr/examples/client.rs')}: 551 lines outside tests (at most 550)",
    ]


# ---------------------------------------------------------------- Python


def py_lines(n: int) -> str:
    return "".join(f"x{i} = {i}\n" for i in range(n))


def test_a_python_file_over_550_lines_is_named_and_one_of_550_is_not(tmp_path, capsys):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "big.py").write_text(py_lines(551))
    (tmp_path / "pkg" / "full.py").write_text(py_lines(550))
    (tmp_path / "tools").mkdir()
    (tmp_path / "tools" / "tail.py").write_text(py_lines(550) + "x = 0")  # a last line without its newline
    code, out = sizes.main(["--python", str(tmp_path)]), capsys.readouterr().out
    assert code == 1
    assert out.splitlines() == [f"{Path('pkg/big.py')}: 551 lines (at most 550)",
                                f"{Path('tools/tail.py')}: 551 lines (at most 550)"]


def test_python_test_files_and_build_folders_do_not_count(tmp_path, capsys):
    long = py_lines(900)
    for rel in ["pkg/test_long.py", "pkg/long_test.py", "pkg/conftest.py", "tests/python/helper.py",
                "models/tests/ddp_draws.py", ".venv/lib/site.py", "env/lib/site.py", "target/gen.py",
                "pkg/__pycache__/x.py"]:
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(long)
    (tmp_path / "env" / "pyvenv.cfg").write_text("home = /usr/bin\n")  # a virtual environment by another name
    (tmp_path / "pkg" / "small.py").write_text(py_lines(10))
    assert sizes.main(["--python", str(tmp_path)]) == 0
    assert capsys.readouterr().out == ""


def test_the_repository_holds_no_file_over_the_limit(capsys):
    assert sizes.main([]) == 0, capsys.readouterr().out
