"""tools/layers/string_errors.py (scripts/check-layers.sh): on synthetic
crates written to tmp_path, a `pub fn` or a trait method returning
`Result<…, String>` is reported (exit 1, file:line and the function) while
`pub(crate)` functions, `FromStr`, typed errors and test code are not; and
the repository itself has none."""
import importlib.util
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "tools" / "layers" / "string_errors.py"
spec = importlib.util.spec_from_file_location("string_errors", SCRIPT)
string_errors = importlib.util.module_from_spec(spec)
spec.loader.exec_module(string_errors)


def write(root: Path, files: dict) -> Path:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def check(capsys, *args):
    code = string_errors.main([str(a) for a in args])
    return code, capsys.readouterr().out


def test_a_pub_fn_and_a_trait_method_returning_a_string_error_are_named(tmp_path, capsys):
    src = write(tmp_path / "src", {
        "lib.rs": "pub mod gpu;\n",
        "gpu.rs": (
            "pub fn wait_for(d: &Device) -> Result<(), String> {\n    Ok(())\n}\n\n"
            "pub fn read_mapped<T, F: FnOnce(&[u8]) -> T>(read: F)\n"
            "    -> std::result::Result<Vec<T>, std::string::String>\nwhere T: Copy { todo!() }\n\n"
            "pub trait DeviceStage: Send {\n    fn describe(&self) -> String;\n"
            "    fn record(&mut self, w: usize) -> Result<(), String>;\n}\n"
        ),
    })
    code, out = check(capsys, "--rust", src)
    assert code == 1
    assert "gpu.rs:1: pub fn wait_for returns Result<(), String>" in out
    assert "gpu.rs:5: pub fn read_mapped returns std::result::Result<Vec<T>, std::string::String>" in out
    assert "gpu.rs:11: trait DeviceStage's fn record returns Result<(), String>" in out
    assert "describe" not in out


def test_typed_errors_private_functions_from_str_and_tests_pass(tmp_path, capsys):
    src = write(tmp_path / "src", {
        "lib.rs": (
            "pub mod eye;\n"
            "pub fn open() -> Result<String, GpuError> { todo!() }\n"
            "pub fn names() -> Result<Vec<String>, AppError> { todo!() }\n"
            "pub(crate) fn parse(s: &str) -> Result<u8, String> { todo!() }\n"
            "pub(super) fn lower() -> Result<u8, String> { todo!() }\n"
            "fn private() -> Result<u8, String> { todo!() }\n"
            "pub fn doc() -> u8 { let _ = \"pub fn f() -> Result<(), String>\"; 0 }\n"
            "// pub fn g() -> Result<(), String>\n"
        ),
        "eye.rs": (
            "impl std::str::FromStr for Eye {\n    type Err = String;\n"
            "    fn from_str(s: &str) -> Result<Self, String> { todo!() }\n}\n"
            "#[cfg(test)]\nmod tests {\n    pub fn helper() -> Result<(), String> { Ok(()) }\n}\n"
        ),
        "eye_tests.rs": "pub fn helper() -> Result<(), String> { Ok(()) }\n",
        "tests/fixtures.rs": "pub trait T { fn f() -> Result<(), String>; }\n",
    })
    code, out = check(capsys, "--rust", src)
    assert code == 0, out
    assert "no public function nor trait method of 1 Rust crate(s)" in out


def test_the_repository_has_no_string_error_in_a_library_interface(capsys):
    code, out = check(capsys)
    assert code == 0, out


def test_a_test_only_use_line_does_not_end_the_check(tmp_path, capsys):
    src = write(tmp_path / "src", {
        "lib.rs": "#[cfg(test)]\nuse std::fmt;\n\npub fn late() -> Result<(), String> {\n    Ok(())\n}\n"
                  "#[cfg(test)]\nmod tests {}\n",
    })
    code, out = check(capsys, "--rust", src)
    assert code == 1 and "late" in out, out
