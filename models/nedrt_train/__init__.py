"""nedrt trainer: joint optimisation of the DOE and the D-CNN through a
differentiable model of the display (docs/model.md), reading the
same calibration TOML as the Rust simulator and checked against its golden
vectors (tests/golden/vectors.json)."""
