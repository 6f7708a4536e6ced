"""The trainer as a package: installed with its `nedrt-train` command, its
dependencies those of requirements.txt, and the calibration an argument
(by default calib/default.toml under the current directory, never looked up
beside the package)."""
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import nedrt_train
from nedrt_train import calib as calib_mod

MODELS = Path(__file__).resolve().parents[1]
REPO = MODELS.parent
ENV = dict(os.environ, OMP_NUM_THREADS="1")


def run(args, cwd):
    return subprocess.run(args, capture_output=True, text=True, env=ENV, cwd=cwd, timeout=300)


def test_pyproject_dependencies_are_the_requirements():
    project = tomllib.loads((MODELS / "pyproject.toml").read_text())["project"]
    pinned = {}
    for line in (MODELS / "requirements.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            name, version = line.split("==")
            pinned[name.lower()] = version
    declared = {}
    for dep in project["dependencies"] + project["optional-dependencies"]["test"]:
        name, version = re.fullmatch(r"([A-Za-z0-9_.-]+)>=(\S+)", dep).groups()
        declared[name.lower()] = version
    assert declared == pinned
    assert project["scripts"]["nedrt-train"] == "nedrt_train.cli:main"


def test_the_package_is_the_one_in_models_and_looks_up_no_repository():
    assert Path(nedrt_train.__file__).resolve().parent == MODELS / "nedrt_train"
    for source in (MODELS / "nedrt_train").glob("*.py"):
        text = source.read_text()
        assert "parents[" not in text and "sys.path" not in text, source.name


def test_nedrt_train_command_has_the_three_subcommands():
    exe = Path(sys.executable).with_name("nedrt-train")
    assert exe.exists(), "install the trainer: pip install --no-build-isolation -e models"
    out = run([str(exe), "--help"], cwd=REPO)
    assert out.returncode == 0 and all(c in out.stdout for c in ["train", "design", "export"]), out.stdout
    out = run([str(exe), "train", "--help"], cwd=REPO)
    assert out.returncode == 0 and "nedrt-train train" in out.stdout and "--calib FILE" in out.stdout
    out = run([str(exe), "frobnicate"], cwd=REPO)
    assert out.returncode == 2 and "unknown command 'frobnicate'" in out.stderr
    # python -m nedrt_train is the same command.
    out = run([sys.executable, "-m", "nedrt_train", "design", "--help"], cwd=REPO)
    assert out.returncode == 0 and "--target" in out.stdout


def test_the_default_calibration_is_under_the_current_directory(tmp_path):
    assert calib_mod.resolve(cwd=REPO) == REPO / "calib" / "default.toml"
    assert calib_mod.resolve("tests/data/small-aperture.toml", cwd=REPO) == REPO / "tests/data/small-aperture.toml"
    with pytest.raises(FileNotFoundError, match=re.escape(str(tmp_path / "calib" / "default.toml"))):
        calib_mod.resolve(cwd=tmp_path)
    with pytest.raises(FileNotFoundError, match="nope.toml"):
        calib_mod.resolve("nope.toml", cwd=tmp_path)
    # Every command says which file it did not find, and nothing is trained.
    for args in (["train", "--preset", "smoke"], ["design", "--target", "allsharp"]):
        out = run([sys.executable, "-m", "nedrt_train", *args, "--out", str(tmp_path / "run")], cwd=tmp_path)
        assert out.returncode != 0
        assert f"{tmp_path / 'calib' / 'default.toml'}: calibration file not found" in out.stderr, out.stderr
        assert not (tmp_path / "run").exists()
    out = run([sys.executable, "-m", "nedrt_train.train", "--preset", "smoke", "--calib", "missing.toml",
               "--out", str(tmp_path / "run")], cwd=tmp_path)
    assert out.returncode != 0 and f"{tmp_path / 'missing.toml'}: calibration file not found" in out.stderr
