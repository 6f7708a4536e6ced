//! Texels from a swapchain to what the service takes: projection views as
//! RGBA8 of the view's size, quads as premultiplied linear RGBA f32 of the
//! size they cover on the panel.

/// The sRGB EOTF (IEC 61966-2-1): code in [0, 1] to linear.
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Bilinear resampling of `channels`-channel texels from `from` to `to`
/// (width, height), sampling at texel centres with edges clamped. The
/// identity when the sizes agree.
pub fn resample(
    src: &[f32],
    from: (usize, usize),
    to: (usize, usize),
    channels: usize,
) -> Vec<f32> {
    resample_region(src, from, Region::WHOLE, to, channels)
}

/// A part of an image, in fractions of its width and height from its top
/// left corner: `[u0, v0, u1, v1]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Region(pub [f32; 4]);

impl Region {
    pub const WHOLE: Region = Region([0.0, 0.0, 1.0, 1.0]);
}

/// `resample` of the part `region` of `src` (bilinear, texel centres).
pub fn resample_region(
    src: &[f32],
    from: (usize, usize),
    region: Region,
    to: (usize, usize),
    channels: usize,
) -> Vec<f32> {
    if from == to && region == Region::WHOLE {
        return src.to_vec();
    }
    let (sw, sh) = from;
    let (dw, dh) = to;
    let [u0, v0, u1, v1] = region.0;
    let mut out = vec![0.0; dw * dh * channels];
    let axis = |d: usize, dn: usize, sn: usize, a: f32, b: f32| {
        let s = (a * sn as f32 + (d as f32 + 0.5) * (b - a) * sn as f32 / dn as f32 - 0.5)
            .clamp(0.0, (sn - 1) as f32);
        let i = s.floor() as usize;
        (i, (i + 1).min(sn - 1), s - i as f32)
    };
    for y in 0..dh {
        let (y0, y1, fy) = axis(y, dh, sh, v0, v1);
        for x in 0..dw {
            let (x0, x1, fx) = axis(x, dw, sw, u0, u1);
            for c in 0..channels {
                let at = |xx: usize, yy: usize| src[(yy * sw + xx) * channels + c];
                let top = at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx;
                let bottom = at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx;
                out[(y * dw + x) * channels + c] = top * (1.0 - fy) + bottom * fy;
            }
        }
    }
    out
}

/// A projection view's RGBA8 texels at the view's size: unchanged when the
/// application rendered at the recommended size (one texel, one panel
/// pixel), else resampled in the encoding the texels have.
pub fn projection_rgba8(texels: &[u8], from: (usize, usize), to: (usize, usize)) -> Vec<u8> {
    if from == to {
        return texels.to_vec();
    }
    let f: Vec<f32> = texels.iter().map(|&b| f32::from(b)).collect();
    resample(&f, from, to, 4)
        .into_iter()
        .map(|v| v.round().clamp(0.0, 255.0) as u8)
        .collect()
}

/// How a quad's alpha is read (XrCompositionLayerFlags).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QuadAlpha {
    /// BLEND_TEXTURE_SOURCE_ALPHA: without it the quad is opaque.
    pub blend: bool,
    /// UNPREMULTIPLIED_ALPHA: colours are not yet multiplied by alpha.
    pub unpremultiplied: bool,
}

/// The part `region` of a quad's texels as premultiplied linear RGBA f32
/// at the panel size it covers.
pub fn quad_rgba(
    texels: &[u8],
    srgb: bool,
    alpha: QuadAlpha,
    from: (usize, usize),
    region: Region,
    to: (usize, usize),
) -> Vec<f32> {
    let mut f = Vec::with_capacity(texels.len());
    for p in texels.chunks_exact(4) {
        let a = if alpha.blend {
            f32::from(p[3]) / 255.0
        } else {
            1.0
        };
        let scale = if alpha.blend && alpha.unpremultiplied {
            a
        } else {
            1.0
        };
        for &c in &p[..3] {
            let v = f32::from(c) / 255.0;
            let linear = if srgb { srgb_to_linear(v) } else { v };
            // Premultiplied colour never exceeds its alpha; an application
            // that breaks this would be refused by the service.
            f.push((linear * scale).min(a));
        }
        f.push(a);
    }
    resample_region(&f, from, region, to, 4)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_decodes_at_its_anchors() {
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-6);
        assert!((srgb_to_linear(0.5) - 0.214_041).abs() < 1e-5);
    }

    #[test]
    fn resampling_keeps_a_constant_and_the_identity() {
        let src = vec![0.25_f32; 5 * 3 * 4];
        let out = resample(&src, (5, 3), (7, 2), 4);
        assert_eq!(out.len(), 7 * 2 * 4);
        assert!(out.iter().all(|&v| (v - 0.25).abs() < 1e-6));
        let ramp: Vec<f32> = (0..6).map(|i| i as f32).collect();
        assert_eq!(resample(&ramp, (6, 1), (6, 1), 1), ramp);
        // Halving a ramp averages neighbours.
        assert_eq!(resample(&ramp, (6, 1), (3, 1), 1), vec![0.5, 2.5, 4.5]);
    }

    #[test]
    fn quads_are_premultiplied_and_opaque_without_blending() {
        let texel = [255u8, 0, 0, 128];
        let opaque = quad_rgba(
            &texel,
            false,
            QuadAlpha {
                blend: false,
                unpremultiplied: false,
            },
            (1, 1),
            Region::WHOLE,
            (1, 1),
        );
        assert_eq!(opaque, vec![1.0, 0.0, 0.0, 1.0]);
        let un = quad_rgba(
            &texel,
            false,
            QuadAlpha {
                blend: true,
                unpremultiplied: true,
            },
            (1, 1),
            Region::WHOLE,
            (1, 1),
        );
        let a = 128.0 / 255.0;
        assert!((un[0] - a).abs() < 1e-6 && (un[3] - a).abs() < 1e-6);
    }
}
