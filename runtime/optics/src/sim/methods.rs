//! The display systems compared (docs/model.md §12, §17): which optics
//! sit in the eyepiece, which PSFs the eye sees at an accommodation, and how
//! the frame is preprocessed.

use crate::PsfSpec;
use nedrt_core::calib::Calibration;

/// What is in the eyepiece.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Optics {
    /// The refractive lens alone.
    Lens,
    /// Lens plus the DOE.
    Doe,
}

/// A simulated display system.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Method {
    /// Lens only, no preprocessing.
    Conventional,
    /// Accommodation-invariant display (Konrad et al. 2017, discrete mode)
    /// with Wiener deconvolution of the time-averaged PSF.
    Ai,
    /// Lens + DOE, no preprocessing.
    DoeOnly,
    /// Lens + DOE with Wiener deconvolution instead of the D-CNN.
    DoeWiener,
    /// Lens + co-designed DOE + D-CNN (the paper's system).
    Proposed,
    /// Lens alone with a D-CNN trained for it (ablation).
    LensDcnn,
}

impl Method {
    pub const ALL: [Method; 6] = [
        Method::Conventional,
        Method::Ai,
        Method::DoeOnly,
        Method::DoeWiener,
        Method::Proposed,
        Method::LensDcnn,
    ];

    /// The methods that need no trained model.
    pub const BUILT_IN: [Method; 4] = [
        Method::Conventional,
        Method::Ai,
        Method::DoeOnly,
        Method::DoeWiener,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Method::Conventional => "conventional",
            Method::Ai => "ai",
            Method::DoeOnly => "doe-only",
            Method::DoeWiener => "doe+wiener",
            Method::Proposed => "proposed",
            Method::LensDcnn => "lens+dcnn",
        }
    }

    pub fn optics(self) -> Optics {
        match self {
            Method::Conventional | Method::Ai | Method::LensDcnn => Optics::Lens,
            Method::DoeOnly | Method::DoeWiener | Method::Proposed => Optics::Doe,
        }
    }

    /// The method that shows a frame unprocessed through `optics`: what an
    /// externally made display image is seen through.
    pub fn unprocessed(optics: Optics) -> Method {
        match optics {
            Optics::Lens => Method::Conventional,
            Optics::Doe => Method::DoeOnly,
        }
    }

    /// Whether the frame is preprocessed by a D-CNN.
    pub fn uses_dcnn(self) -> bool {
        matches!(self, Method::Proposed | Method::LensDcnn)
    }

    /// Whether the frame is Wiener-prefiltered.
    pub fn uses_wiener(self) -> bool {
        matches!(self, Method::Ai | Method::DoeWiener)
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl nedrt_core::Named for Method {
    const ALL: &'static [Self] = &Method::ALL;
    fn name(self) -> &'static str {
        Method::name(self)
    }
    fn help(self) -> &'static str {
        match self {
            Method::Conventional => "lens only, no preprocessing",
            Method::Ai => "accommodation-invariant display with its Wiener prefilter",
            Method::DoeOnly => "lens + DOE, no preprocessing",
            Method::DoeWiener => "lens + DOE with its Wiener prefilter",
            Method::Proposed => "lens + co-designed DOE + D-CNN trained with it",
            Method::LensDcnn => "lens alone with a D-CNN trained for it",
        }
    }
}

impl nedrt_core::Named for Optics {
    const ALL: &'static [Self] = &[Optics::Lens, Optics::Doe];
    fn name(self) -> &'static str {
        match self {
            Optics::Lens => "lens",
            Optics::Doe => "doe",
        }
    }
    fn help(self) -> &'static str {
        match self {
            Optics::Lens => "the refractive lens alone",
            Optics::Doe => "lens plus the DOE",
        }
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = Method::ALL.iter().map(|m| m.name()).collect();
                format!("unknown method {s:?}; choose one of {}", names.join(", "))
            })
    }
}

/// The PSFs the eye integrates for `method` at `accommodation_d`, channel
/// `channel`, with their time weights (one term except for the AI display).
pub fn psf_terms(
    calib: &Calibration,
    method: Method,
    accommodation_d: f64,
    channel: usize,
) -> Vec<(PsfSpec, f64)> {
    match method {
        Method::Ai => {
            // The tunable lens puts the design colour's image at each plane;
            // other colours keep the lens's chromatic offset V_λ − V_λ0.
            let offset =
                calib.seen_vergence_d(channel) - calib.seen_vergence_d(calib.design_channel);
            let w = 1.0 / calib.ai_planes_d.len() as f64;
            calib
                .ai_planes_d
                .iter()
                .map(|plane| {
                    let psi = calib.psi_for_vergence(channel, plane + offset - accommodation_d);
                    (
                        PsfSpec {
                            channel,
                            psi_rad: psi,
                        },
                        w,
                    )
                })
                .collect()
        }
        _ => vec![(
            PsfSpec {
                channel,
                psi_rad: calib.psi_rad(channel, accommodation_d),
            },
            1.0,
        )],
    }
}

/// The target blur h_b: lens only, Ψ = Ψ_b at every wavelength (docs/model.md §10).
pub fn target_blur_spec(calib: &Calibration, channel: usize) -> PsfSpec {
    PsfSpec {
        channel,
        psi_rad: calib.target_blur_psi_rad,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_names_explain() {
        for m in Method::ALL {
            assert_eq!(m.name().parse::<Method>(), Ok(m));
        }
        assert!(
            "foo"
                .parse::<Method>()
                .unwrap_err()
                .contains("conventional")
        );
    }

    #[test]
    fn ai_planes_keep_chromatic_offsets() {
        let c = Calibration::default_embedded().expect("calib");
        // Green at 1.5 D: one plane exactly in focus.
        let terms = psf_terms(&c, Method::Ai, 1.5, c.design_channel);
        assert_eq!(terms.len(), 3);
        assert!(terms.iter().any(|(s, _)| s.psi_rad.abs() < 1e-9));
        assert!((terms.iter().map(|t| t.1).sum::<f64>() - 1.0).abs() < 1e-12);
        // Red at 1.5 D: the in-focus plane is off by V_R − V_G ≈ 0.22 D.
        let red = psf_terms(&c, Method::Ai, 1.5, 0);
        let best = red
            .iter()
            .map(|(s, _)| s.psi_rad.abs())
            .fold(f64::MAX, f64::min);
        let want = c
            .psi_for_vergence(0, c.vergence_d(0) - c.vergence_d(1))
            .abs();
        assert!((best - want).abs() < 1e-9);
    }
}
