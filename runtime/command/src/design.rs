//! Display designs selected by name (`--design multifocal|allsharp|FILE`):
//! a small TOML naming a DOE file and the Wiener constant K tuned for it,
//! so that one flag switches the element and its prefilter together
//! (designs/README.md; the DOE stage that makes them is docs/training.md).

use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::AppError;
use nedrt_core::calib::Calibration;

/// Folder the shipped designs live in, relative to the working directory
/// (like the default `models/dcnn.onnx`).
pub const DESIGNS_DIR: &str = "designs";

/// The file as written (strict: an unknown or misspelt key is an error).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDesign {
    name: String,
    /// What the design optimises: "multifocal" or "allsharp".
    target: String,
    /// DOE file (fabrication pitch), relative to the design file.
    doe: PathBuf,
    /// Wiener constant K of the doe+wiener prefilter for this DOE.
    wiener_k: f64,
    /// Design card (recipe, wall time, data, validation table), relative to the design file.
    card: Option<PathBuf>,
}

/// A resolved design: paths absolute or relative to the working directory.
#[derive(Debug, Clone, PartialEq)]
pub struct Design {
    pub name: String,
    pub target: String,
    pub source: PathBuf,
    pub doe: PathBuf,
    pub wiener_k: f64,
    pub card: Option<PathBuf>,
}

impl Design {
    /// The objective the design was made for: the sharp image (`allsharp`)
    /// or the multifocal target (anything else).
    pub fn objective(&self) -> nedrt_optics::sim::Objective {
        if self.target == "allsharp" {
            nedrt_optics::sim::Objective::Sharp
        } else {
            nedrt_optics::sim::Objective::Target
        }
    }

    /// `arg` is a design name (`designs/NAME.toml`) or the path of a design file.
    pub fn resolve(arg: &str) -> Result<Self, AppError> {
        let as_path = Path::new(arg);
        let path = if arg.ends_with(".toml") || as_path.components().count() > 1 {
            as_path.to_path_buf()
        } else {
            Path::new(DESIGNS_DIR).join(format!("{arg}.toml"))
        };
        if !path.exists() {
            return Err(AppError::option(
                format!("--design {arg}"),
                format!(
                    "{} does not exist (shipped designs: {})",
                    path.display(),
                    shipped_names().join(", ")
                ),
            ));
        }
        Self::load(&path)
    }

    /// Reads and validates a design file, naming it and the field on error.
    pub fn load(path: &Path) -> Result<Self, AppError> {
        let bad = |reason: String| AppError::output(path, format!("invalid design: {reason}"));
        let text = std::fs::read_to_string(path).map_err(|e| bad(e.to_string()))?;
        let raw: RawDesign = toml::from_str(&text).map_err(|e| bad(e.to_string()))?;
        if !matches!(raw.target.as_str(), "multifocal" | "allsharp") {
            return Err(bad(format!(
                "target = {:?}: expected \"multifocal\" or \"allsharp\"",
                raw.target
            )));
        }
        if !(raw.wiener_k.is_finite() && raw.wiener_k > 0.0) {
            return Err(bad(format!(
                "wiener_k = {}: must be a positive number",
                raw.wiener_k
            )));
        }
        let base = path.parent().unwrap_or(Path::new(""));
        let doe = base.join(&raw.doe);
        if !doe.exists() {
            return Err(bad(format!(
                "doe = {:?}: {} does not exist",
                raw.doe,
                doe.display()
            )));
        }
        Ok(Self {
            name: raw.name,
            target: raw.target,
            source: path.to_path_buf(),
            doe,
            wiener_k: raw.wiener_k,
            card: raw.card.map(|c| base.join(c)),
        })
    }

    /// Every design file in `designs/` (name order), for the studies that
    /// compare the shipped designs; none when the folder is missing.
    pub fn shipped() -> Result<Vec<Self>, AppError> {
        let mut paths: Vec<PathBuf> = match std::fs::read_dir(DESIGNS_DIR) {
            Ok(dir) => dir
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|x| x == "toml"))
                .collect(),
            Err(_) => Vec::new(),
        };
        paths.sort();
        paths.iter().map(|p| Self::load(p)).collect()
    }

    /// `--designs` of the studies: the named designs, or all shipped ones
    /// when none are named.
    pub fn resolve_list(names: Option<&[String]>) -> Result<Vec<Self>, AppError> {
        match names {
            None => Self::shipped(),
            Some(names) => names.iter().map(|n| Self::resolve(n)).collect(),
        }
    }

    /// A simulator of this design: its DOE, and `base` with its K.
    pub fn simulator(
        &self,
        mut base: Calibration,
        cache: nedrt_optics::cache::PsfCache,
    ) -> Result<nedrt_optics::sim::Simulator, AppError> {
        let hash = nedrt_optics::doe_file::load(&self.doe, &base)?.content_hash();
        self.apply(&mut base, hash);
        Ok(nedrt_optics::sim::Simulator::new(
            base,
            Some(&self.doe),
            cache,
        )?)
    }

    /// The calibration with this design's K for the DOE's Wiener prefilter,
    /// marked as tuned for the design's DOE (`doe_hash`, its content hash).
    pub fn apply(&self, calib: &mut Calibration, doe_hash: String) {
        calib.wiener.doe_k = self.wiener_k;
        calib.wiener.doe_k_tuned_for = doe_hash;
    }
}

/// Names of the design files in `designs/`, for error messages.
fn shipped_names() -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(DESIGNS_DIR)
        .map(|dir| {
            dir.filter_map(|e| e.ok())
                .filter_map(|e| {
                    let p = e.path();
                    let stem = p.file_stem()?.to_string_lossy().into_owned();
                    (p.extension()? == "toml").then_some(stem)
                })
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    if names.is_empty() {
        names.push("none found in ./designs".into());
    }
    names
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).expect("write");
        p
    }

    #[test]
    fn a_design_resolves_its_doe_beside_it_and_sets_k() {
        let dir = tempfile::tempdir().expect("tempdir");
        write(dir.path(), "x.safetensors", "");
        let p = write(
            dir.path(),
            "d.toml",
            "name = \"d\"\ntarget = \"allsharp\"\ndoe = \"x.safetensors\"\nwiener_k = 0.01\n",
        );
        let d = Design::resolve(p.to_str().expect("utf8")).expect("valid");
        assert_eq!(d.doe, dir.path().join("x.safetensors"));
        let mut c = Calibration::default_embedded().expect("calib");
        d.apply(&mut c, "abc".into());
        assert_eq!(
            (c.wiener.doe_k, c.wiener.doe_k_tuned_for.as_str()),
            (0.01, "abc")
        );
    }

    #[test]
    fn bad_designs_name_the_file_and_field() {
        let dir = tempfile::tempdir().expect("tempdir");
        write(dir.path(), "x.safetensors", "");
        for (text, needle) in [
            (
                "name = \"d\"\ntarget = \"sharp\"\ndoe = \"x.safetensors\"\nwiener_k = 0.01\n",
                "target",
            ),
            (
                "name = \"d\"\ntarget = \"allsharp\"\ndoe = \"x.safetensors\"\nwiener_k = -1\n",
                "wiener_k",
            ),
            (
                "name = \"d\"\ntarget = \"allsharp\"\ndoe = \"missing.safetensors\"\nwiener_k = 0.1\n",
                "missing",
            ),
            (
                "name = \"d\"\ntarget = \"allsharp\"\ndoe = \"x.safetensors\"\nwiener_k = 0.1\nk = 2\n",
                "unknown field",
            ),
        ] {
            let p = write(dir.path(), "bad.toml", text);
            let e = Design::load(&p).expect_err(needle).to_string();
            assert!(e.contains("bad.toml") && e.contains(needle), "{e}");
        }
        let e = Design::resolve("no-such-design")
            .expect_err("missing")
            .to_string();
        assert!(e.contains("designs/no-such-design.toml"), "{e}");
    }
}
