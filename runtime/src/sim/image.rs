//! Planar RGB images of linear intensity (docs/model.md §1, §9) and the grid
//! operations of the model: up2 (display pixel → 2×2 retinal cells),
//! symmetric extension, cropping.

/// A planar image: `planes[c]` is row-major `height`×`width`, values are linear intensity.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub planes: Vec<Vec<f32>>,
}

impl Image {
    /// A black image with `channels` planes.
    pub fn zeros(width: usize, height: usize, channels: usize) -> Self {
        Self {
            width,
            height,
            planes: vec![vec![0.0; width * height]; channels],
        }
    }

    /// Builds an image from planes, checking their sizes.
    pub fn from_planes(width: usize, height: usize, planes: Vec<Vec<f32>>) -> Self {
        assert!(
            planes.iter().all(|p| p.len() == width * height),
            "plane size mismatch"
        );
        Self {
            width,
            height,
            planes,
        }
    }

    pub fn channels(&self) -> usize {
        self.planes.len()
    }

    /// up2: each pixel becomes a 2×2 block (the square pixel aperture on the retinal grid).
    pub fn up2(&self) -> Self {
        let (w, h) = (self.width, self.height);
        let planes = self
            .planes
            .iter()
            .map(|p| {
                let mut out = vec![0.0; 4 * w * h];
                for y in 0..2 * h {
                    let src = &p[(y / 2) * w..(y / 2 + 1) * w];
                    let dst = &mut out[y * 2 * w..(y + 1) * 2 * w];
                    for (x, v) in src.iter().enumerate() {
                        dst[2 * x] = *v;
                        dst[2 * x + 1] = *v;
                    }
                }
                out
            })
            .collect();
        Self::from_planes(2 * w, 2 * h, planes)
    }

    /// Symmetric (half-sample, edge repeated) extension to `width`×`height`,
    /// the original at offset (`left`, `top`); repeats the mirroring as needed.
    pub fn extend_symmetric(&self, left: usize, top: usize, width: usize, height: usize) -> Self {
        let planes = self
            .planes
            .iter()
            .map(|p| extend_plane(p, self.width, self.height, left, top, width, height))
            .collect();
        Self::from_planes(width, height, planes)
    }

    /// The `width`×`height` block starting at (`left`, `top`).
    pub fn crop(&self, left: usize, top: usize, width: usize, height: usize) -> Self {
        assert!(
            left + width <= self.width && top + height <= self.height,
            "crop out of range"
        );
        let planes = self
            .planes
            .iter()
            .map(|p| {
                let mut out = Vec::with_capacity(width * height);
                for y in top..top + height {
                    out.extend_from_slice(&p[y * self.width + left..y * self.width + left + width]);
                }
                out
            })
            .collect();
        Self::from_planes(width, height, planes)
    }

    /// Clamps every value to [0, 1], the panel's range.
    pub fn clamped(mut self) -> Self {
        for p in &mut self.planes {
            p.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
        }
        self
    }

    /// Mean of each plane.
    pub fn plane_means(&self) -> Vec<f64> {
        self.planes
            .iter()
            .map(|p| p.iter().map(|v| *v as f64).sum::<f64>() / p.len().max(1) as f64)
            .collect()
    }
}

/// Index into 0..n of position `i` under symmetric extension (period 2n).
pub fn symmetric_index(i: isize, n: usize) -> usize {
    let period = 2 * n as isize;
    let k = i.rem_euclid(period);
    if k < n as isize {
        k as usize
    } else {
        (period - 1 - k) as usize
    }
}

/// Symmetric extension of one plane (see [`Image::extend_symmetric`]).
pub fn extend_plane(
    p: &[f32],
    w: usize,
    h: usize,
    left: usize,
    top: usize,
    width: usize,
    height: usize,
) -> Vec<f32> {
    let xs: Vec<usize> = (0..width)
        .map(|x| symmetric_index(x as isize - left as isize, w))
        .collect();
    let mut out = Vec::with_capacity(width * height);
    for y in 0..height {
        let row = &p[symmetric_index(y as isize - top as isize, h) * w..][..w];
        out.extend(xs.iter().map(|&x| row[x]));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn up2_makes_2x2_blocks() {
        let im = Image::from_planes(2, 1, vec![vec![0.25, 0.75]]);
        let up = im.up2();
        assert_eq!((up.width, up.height), (4, 2));
        assert_eq!(
            up.planes[0],
            vec![0.25, 0.25, 0.75, 0.75, 0.25, 0.25, 0.75, 0.75]
        );
    }

    #[test]
    fn symmetric_extension_repeats_the_edge_and_wraps_far() {
        assert_eq!(
            (-4..7).map(|i| symmetric_index(i, 3)).collect::<Vec<_>>(),
            vec![2, 2, 1, 0, 0, 1, 2, 2, 1, 0, 0]
        );
        // Extension commutes with up2 (the reason for half-sample symmetry).
        let im = Image::from_planes(3, 2, vec![vec![0.1, 0.2, 0.3, 0.4, 0.5, 0.6]]);
        let a = im.extend_symmetric(2, 1, 8, 5).up2();
        let b = im.up2().extend_symmetric(4, 2, 16, 10);
        assert_eq!(a, b);
    }

    #[test]
    fn crop_inverts_extension() {
        let im = Image::from_planes(3, 2, vec![vec![0.1, 0.2, 0.3, 0.4, 0.5, 0.6]]);
        assert_eq!(im.extend_symmetric(5, 4, 20, 11).crop(5, 4, 3, 2), im);
    }
}
