//! The D-CNN's sections of the stability study, as typed rows:
//! accommodations and content off its training distribution, frame sizes,
//! and f16 against f32 on the GPU.

use std::path::Path;
use std::sync::Arc;

use serde::Serialize;

use super::DEPTHS_D;
use crate::AppError;
use nedrt_infer::content::content_set;
use nedrt_infer::{BackendKind, BackendOptions, Dcnn, Precision};
use nedrt_optics::sim::metrics::psnr;
use nedrt_optics::sim::wiener::WienerFilter;
use nedrt_optics::sim::{Image, Method, Simulator};

/// What a D-CNN is built on: its input, and the display image the panel
/// would show without the network (what its margin is measured against).
#[derive(Debug, Clone)]
pub enum Base {
    /// The network sees the frame; without it the DOE shows the frame (doe-only).
    Frame,
    /// The network sees its optics' Wiener prefilter before the clamp;
    /// without it the DOE shows the clamped Wiener.
    Wiener(Arc<WienerFilter>),
}

impl Base {
    /// The network's input for `frame`.
    pub fn network_input(&self, frame: &Image) -> Image {
        match self {
            Base::Frame => frame.clone(),
            Base::Wiener(w) => w.apply_unclamped(frame),
        }
    }

    /// The display image without the network.
    pub fn display(&self, frame: &Image) -> Image {
        match self {
            Base::Frame => frame.clone(),
            Base::Wiener(w) => w.apply(frame),
        }
    }

    /// The base's name in tables.
    pub fn name(&self) -> String {
        match self {
            Base::Frame => "doe-only".into(),
            Base::Wiener(w) => format!("doe+wiener (K = {:.3})", w.k_reg),
        }
    }
}

/// Mean PSNR vs sharp at one accommodation.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct DepthRow {
    pub accommodation_d: f64,
    pub proposed: f64,
    /// The same DOE without the network (its [`Base`]).
    pub base: f64,
    pub conventional: f64,
}

/// The D-CNN on one synthetic content frame.
#[derive(Debug, Clone, Serialize)]
pub struct ContentRow {
    pub content: String,
    /// Mean PSNR over 0–2.5 D.
    pub proposed: f64,
    pub base: f64,
    /// Mean |display − base display|: what the network changed.
    pub changed: f64,
    pub finite: bool,
    /// Share of the output's and the input's values at 0 or 1.
    #[serde(skip)]
    pub at_bounds: [f64; 2],
}

/// Range (lowest, highest) of the proposed − base margin over a set of
/// accommodations.
pub type Margin = (f64, f64);

/// The D-CNN off its training accommodations and content.
#[derive(Debug, Clone, Serialize)]
pub struct DcnnSection {
    /// What the margins are measured against ([`Base::name`]).
    pub base: String,
    pub accommodations: Vec<DepthRow>,
    pub content: Vec<ContentRow>,
    /// Margins at trained depths, untrained ones inside the calibrated
    /// range, and beyond it.
    #[serde(skip)]
    pub margins: [Margin; 3],
    #[serde(skip)]
    pub range_max_d: f64,
    #[serde(skip)]
    pub content_size: usize,
    #[serde(skip)]
    pub flat_shift: f32,
}

/// The D-CNN at accommodations it was not trained at, and on content
/// unlike its training data.
/// `wiener_k`: the K of the Wiener stage in front of the network (its
/// model card's), or `None` for a network that sees the frame. Returns the
/// section and the network's [`Base`], for the other sections.
pub fn depths_and_content(
    sim: &Simulator,
    dcnn: &mut Dcnn,
    wiener_k: Option<f64>,
    inputs: &[Image],
    content_size: usize,
) -> Result<(DcnnSection, Base), AppError> {
    // The base display is seen through the D-CNN's own optics (its DOE),
    // as doe-only would be.
    let methods = [Method::Proposed, Method::Conventional];
    let depths = crate::tradeoff::quality::headline_depths(&sim.calib);
    let mut all_depths = DEPTHS_D.to_vec();
    all_depths.extend(depths.iter().filter(|d| !DEPTHS_D.contains(d)));
    let prepared = sim.prepare(&methods, &all_depths, &nedrt_core::progress::Silent)?;
    let base = match wiener_k {
        None => Base::Frame,
        Some(k) => Base::Wiener(Arc::new(prepared.wiener_filter(Method::Proposed, k)?)),
    };
    let mut run = |frame: &Image| -> Result<(Image, Image), AppError> {
        Ok((
            dcnn.run_frame(&base.network_input(frame))?,
            base.display(frame),
        ))
    };
    let displays: Vec<(Image, Image)> = inputs.iter().map(&mut run).collect::<Result<_, _>>()?;
    let mut accommodations = Vec::new();
    for &d in &DEPTHS_D {
        let mut s = [0.0; 3];
        for (i, input) in inputs.iter().enumerate() {
            let sharp = input.up2();
            let (display, base_display) = &displays[i];
            s[0] += psnr(&prepared.perceived(Method::Proposed, display, d)?, &sharp);
            s[1] += psnr(
                &prepared.perceived(Method::Proposed, base_display, d)?,
                &sharp,
            );
            s[2] += psnr(&prepared.perceived(Method::Conventional, input, d)?, &sharp);
        }
        s.iter_mut().for_each(|v| *v /= inputs.len() as f64);
        accommodations.push(DepthRow {
            accommodation_d: d,
            proposed: s[0],
            base: s[1],
            conventional: s[2],
        });
    }
    let c = &sim.calib;
    let hi = c.range_d[1];
    let trained =
        |d: f64| c.is_main_depth(d) || c.intermediate_d.iter().any(|x| (x - d).abs() < 1e-9);
    let margin = |pick: &dyn Fn(f64) -> bool| {
        let m: Vec<f64> = accommodations
            .iter()
            .filter(|r| pick(r.accommodation_d))
            .map(|r| r.proposed - r.base)
            .collect();
        (
            m.iter().copied().fold(f64::INFINITY, f64::min),
            m.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        )
    };
    let margins = [
        margin(&|d| trained(d)),
        margin(&|d| !trained(d) && d <= hi),
        margin(&|d| d > hi),
    ];

    let mut content = Vec::new();
    for c in &content_set(content_size) {
        let (out, base_display) = run(&c.image)?;
        let sharp = c.image.up2();
        let mean_psnr = |m: Method, d: &Image| -> Result<f64, AppError> {
            let mut s = 0.0;
            for &z in &depths {
                s += psnr(&prepared.perceived(m, d, z)?, &sharp);
            }
            Ok(s / depths.len() as f64)
        };
        let n = (3 * content_size * content_size) as f64;
        let changed = out
            .data()
            .iter()
            .zip(base_display.data().iter())
            .map(|(a, b)| f64::from((a - b).abs()))
            .sum::<f64>()
            / n;
        let bounds = |im: &Image| {
            im.data()
                .iter()
                .filter(|v| **v <= 0.0 || **v >= 1.0)
                .count() as f64
                / n
        };
        content.push(ContentRow {
            content: c.name.to_string(),
            proposed: mean_psnr(Method::Proposed, &out)?,
            base: mean_psnr(Method::Proposed, &base_display)?,
            changed,
            finite: out.data().iter().all(|v| v.is_finite()),
            at_bounds: [bounds(&out), bounds(&c.image)],
        });
    }
    let flat_shift = dcnn.flat_field_shift()?;
    Ok((
        DcnnSection {
            base: base.name(),
            accommodations,
            content,
            margins,
            range_max_d: hi,
            content_size,
            flat_shift,
        },
        base,
    ))
}

/// A crop run alone against the same pixels of the whole image's output.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct SizeRow {
    pub width: usize,
    pub height: usize,
    pub max_abs: f32,
    pub mean_abs: f64,
    /// Largest difference ≥ 32 px from the crop's edges (none when the
    /// crop is too small to have such pixels).
    pub inner_max_abs: Option<f32>,
}

/// The D-CNN on frame sizes it never saw: crops of an image (the
/// network's input: for a network behind a Wiener stage, the Wiener's
/// output of the whole image) against the same region of the whole
/// image's output. Crops start at (200, 200), nearer the origin where the
/// image is too small for that; sizes larger than the image are left out.
pub fn sizes(dcnn: &mut Dcnn, image: &Image) -> Result<Vec<SizeRow>, AppError> {
    let whole = dcnn.run_frame(image)?;
    let mut rows = Vec::new();
    let sizes = [(1, 1), (7, 5), (8, 8), (36, 20), (100, 75), (160, 160)];
    for (w, h) in sizes
        .into_iter()
        .filter(|&(w, h)| w <= image.width && h <= image.height)
    {
        let (x0, y0) = (200.min(image.width - w), 200.min(image.height - h));
        let crop = image.crop(x0, y0, w, h);
        let out = dcnn.run_frame(&crop)?;
        let reference = whole.crop(x0, y0, w, h);
        let (mut max, mut sum, mut inner) = (0.0f32, 0.0f64, None::<f32>);
        for c in 0..3 {
            for y in 0..h {
                for x in 0..w {
                    let d = (out.plane(c)[y * w + x] - reference.plane(c)[y * w + x]).abs();
                    max = max.max(d);
                    sum += f64::from(d);
                    if x >= 32 && y >= 32 && x + 32 < w && y + 32 < h {
                        inner = Some(inner.unwrap_or(0.0).max(d));
                    }
                }
            }
        }
        rows.push(SizeRow {
            width: w,
            height: h,
            max_abs: max,
            mean_abs: sum / (3 * w * h) as f64,
            inner_max_abs: inner,
        });
    }
    Ok(rows)
}

/// f16 against f32 on one frame.
#[derive(Debug, Clone, Serialize)]
pub struct F16Row {
    pub content: String,
    pub max_abs: f32,
    pub psnr_db: f64,
}

/// f16 against f32 on the wgpu adapter, or why it was not measured.
#[derive(Debug, Clone)]
pub enum F16Section {
    Measured { adapter: String, rows: Vec<F16Row> },
    NotMeasured(String),
    Skipped,
}

impl Serialize for F16Section {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            F16Section::Measured { rows, .. } => rows.serialize(s),
            _ => s.serialize_none(),
        }
    }
}

/// f16 against f32 on the wgpu adapter for the worst-conditioned inputs.
pub fn f16_against_f32(
    model: &Path,
    base: &Base,
    image: &Image,
    content_size: usize,
) -> Result<F16Section, AppError> {
    let open = |precision| {
        Dcnn::load(
            model,
            BackendKind::Wgpu,
            &BackendOptions {
                precision,
                ..Default::default()
            },
        )
    };
    let (mut f32_net, mut f16_net) = match (open(Precision::F32), open(Precision::F16)) {
        (Ok(a), Ok(b)) => (a, b),
        (Err(e), _) | (_, Err(e)) => return Ok(F16Section::NotMeasured(e.to_string())),
    };
    let mut frames: Vec<(String, Image)> = content_set(content_size)
        .into_iter()
        .map(|c| (c.name.to_string(), c.image))
        .collect();
    frames.push((
        "image crop".into(),
        image.crop(0, 0, content_size, content_size),
    ));
    let mut rows = Vec::new();
    for (name, frame) in &frames {
        let input = base.network_input(frame);
        let a = f32_net.run_frame(&input)?;
        let b = f16_net.run_frame(&input)?;
        let max = a
            .data()
            .iter()
            .zip(b.data().iter())
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max);
        rows.push(F16Row {
            content: name.clone(),
            max_abs: max,
            psnr_db: psnr(&b, &a),
        });
    }
    Ok(F16Section::Measured {
        adapter: f16_net.describe(),
        rows,
    })
}
