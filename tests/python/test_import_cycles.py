"""tools/layers/import_cycles.py (scripts/check-layers.sh): on synthetic
crates and packages written to tmp_path, a loop between sibling Rust modules
or between Python modules is reported (exit 1, naming the modules and one
import line per edge) while parent/child uses, acyclic imports and test code
(`#[cfg(test)] mod tests { … }`, tests.rs) are not; and the repository itself
has no loop."""
import importlib.util
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "tools" / "layers" / "import_cycles.py"
spec = importlib.util.spec_from_file_location("import_cycles", SCRIPT)
cycles = importlib.util.module_from_spec(spec)
spec.loader.exec_module(cycles)


def write(root: Path, files: dict) -> Path:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def check(capsys, *args):
    code = cycles.main([str(a) for a in args])
    return code, capsys.readouterr().out


# ------------------------------------------------------------------ Rust


def test_a_loop_between_sibling_rust_modules_is_named_with_its_lines(tmp_path, capsys):
    src = write(tmp_path / "src", {
        "lib.rs": "mod network;\nmod lower;\npub use network::Network;\n",
        "network.rs": "pub struct Network;\n\nimpl Network {\n"
                      "    pub fn read() -> Self { super::lower::lower() }\n}\n",
        "lower/mod.rs": "mod conv;\nuse crate::network::Network;\n"
                        "pub(super) fn lower() -> Network { conv::conv() }\n",
        "lower/conv.rs": "pub(super) fn conv() -> crate::Network { crate::Network }\n",
    })
    code, out = check(capsys, "--rust", src)
    assert code == 1
    assert "among the children of the crate root: lower, network" in out
    assert "lower -> network: " in out and "lower/mod.rs:2: use crate::network::Network;" in out
    assert "network -> lower: " in out and "network.rs:4:" in out


def test_a_loop_deeper_in_the_tree_and_one_through_a_child_are_found(tmp_path, capsys):
    src = write(tmp_path / "src", {
        "lib.rs": "pub mod calib;\npub mod image;\npub mod sim;\n",
        "calib/mod.rs": "mod eye;\nmod raw;\n",
        "calib/eye.rs": "use super::raw::RawEye;\npub const RELIEF: f64 = 15.0;\n",
        "calib/raw.rs": "pub struct RawEye;\nfn relief() -> f64 { super::eye::RELIEF }\n",
        # image's child uses sim's child, sim's child uses image: a loop of image and sim.
        "image.rs": "mod io;\npub struct Image;\n",
        "image/io.rs": "use crate::sim::{convolve::{self, Kernel}};\n",
        "sim/mod.rs": "pub mod convolve;\n",
        "sim/convolve.rs": "pub struct Kernel;\npub fn run(_: &crate::image::Image) {}\n",
    })
    code, out = check(capsys, "--rust", src)
    assert code == 1
    assert "among the children of calib: calib::eye, calib::raw" in out
    assert "calib::raw -> calib::eye: " in out and "raw.rs:2:" in out
    assert "among the children of the crate root: image, sim" in out
    assert "image -> sim: " in out and "image/io.rs:1:" in out


def test_parent_child_uses_and_acyclic_siblings_pass(tmp_path, capsys):
    src = write(tmp_path / "src", {
        "lib.rs": "pub mod network;\nmod lower;\nmod model_file;\npub struct Error;\n"
                  "pub fn load() { model_file::read(); lower::lower(); }\n",
        "network.rs": "//! Not [`crate::lower`]: comments, strings and chars do not count.\n"
                      "pub struct Network(pub u8);\nconst C: char = '\"';\n"
                      "const S: &str = \"super::lower::lower()\";\n"
                      "const R: &str = r#\"crate::lower \"quoted\" \"#;\n"
                      "/* crate::lower::lower() /* nested */ crate::lower */\n"
                      "fn f<'a>(n: &'a Network) -> &'a Network { n }\n",
        "lower/mod.rs": "mod conv;\nuse super::network::Network;\nuse super::Error;\n"
                        "pub(crate) fn lower() -> Network { conv::conv(); Network(0) }\n",
        "lower/conv.rs": "use super::super::Error;\nuse crate::lower::Network;\n"
                         "pub(super) fn conv() -> Option<crate::network::Network> { None }\n",
        "model_file.rs": "use crate::network::Network;\n"
                         "pub fn read() -> Network { crate::lower::lower() }\n",
    })
    code, out = check(capsys, "--rust", src)
    assert code == 0, out
    assert "none among the modules of 1 Rust crate(s) (5 files" in out


def test_rust_test_code_does_not_count(tmp_path, capsys):
    src = write(tmp_path / "src", {
        "lib.rs": "mod a;\nmod b;\n#[cfg(test)]\nmod tests;\n#[cfg(test)]\nmod helpers;\n",
        "a.rs": "use crate::b::B;\npub struct A(B);\n",
        "b.rs": "pub struct B;\n\n#[cfg(test)]\nmod tests {\n    use super::super::a;\n"
                "    #[test]\n    fn t() { let _ = super::super::a::A(super::B); }\n}\n\n"
                "#[cfg(test)]\nfn helper() -> crate::a::A { todo!() }\n",
        "tests.rs": "use crate::a::A;\nuse crate::b::B;\n",
        "helpers.rs": "use crate::a::A;\n",
        "b_tests.rs": "use crate::a::A;\n",
        "tests/more.rs": "use crate::a::A;\n",
    })
    code, out = check(capsys, "--rust", src)
    assert code == 0, out
    # The same use outside the test block is a loop.
    (src / "b.rs").write_text("pub struct B;\nfn f() { let _ = crate::a::A(B); }\n")
    code, out = check(capsys, "--rust", src)
    assert code == 1 and "a, b" in out


# ---------------------------------------------------------------- Python


def test_a_python_loop_through_a_function_level_import_is_named(tmp_path, capsys):
    pkg = write(tmp_path / "nedrt_train", {
        "__init__.py": "",
        "export.py": "import numpy as np\n\n\ndef run():\n    from .radial import profile\n",
        "radial.py": "def taps():\n    from .export import keys_weight\n",
        "train.py": "from nedrt_train.radial import taps\n",
        "loss.py": "import nedrt_train.train\nfrom . import radial\n",
    })
    code, out = check(capsys, "--python", pkg)
    assert code == 1
    assert "import cycle in the Python package nedrt_train" in out and "): export, radial\n" in out
    assert "export -> radial: " in out and "export.py:5: from .radial import profile" in out
    assert "radial -> export: " in out and "radial.py:2:" in out
    # A third module closes a longer loop: all three are named, once.
    (pkg / "radial.py").write_text("import nedrt_train.train\n")
    (pkg / "train.py").write_text("from . import export\n")
    code, out = check(capsys, "--python", pkg)
    assert code == 1 and ": export, radial, train" in out and out.count("import cycle") == 1


def test_acyclic_python_imports_pass(tmp_path, capsys):
    pkg = write(tmp_path / "nedrt_train", {
        "__init__.py": "from .export import save\n",
        "keys.py": "import math\n\nimport numpy as np\n",
        "radial.py": "from .keys import keys_taps\n",
        "export.py": "from .keys import keys_weight\n\n\ndef save():\n    from .radial import keys_taps\n"
                     "    from nedrt_train import radial\n",
    })
    code, out = check(capsys, "--python", pkg)
    assert code == 0, out
    assert "1 Python package(s) (4 modules)" in out


# ------------------------------------------------------------ repository


def test_the_repository_has_no_import_cycle():
    out = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    crates = len(cycles.RUST_CRATES)
    assert f"none among the modules of {crates} Rust crate(s)" in out.stdout and "1 Python package(s)" in out.stdout


def test_the_checks_cover_every_library_crate_of_the_workspace():
    # A crate left off the list is not checked at all: nedrt-stages and
    # nedrt-openxr were, and each held a loop the check did not see.
    sys.path.insert(0, str(SCRIPT.parent))
    from layer_check import RUST_CRATES
    crates = {p.parent.name for p in (REPO / "runtime").glob("*/Cargo.toml")}
    # The entry points are not libraries: the binary (cli) and the Python
    # package's extension (python, one module).
    assert crates - {"cli", "python"} == set(RUST_CRATES), sorted(crates ^ set(RUST_CRATES))
