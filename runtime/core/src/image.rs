//! Planar RGB images of linear intensity (docs/model.md §1, §9) and the grid
//! operations of the model: up2 (display pixel → 2×2 retinal cells),
//! symmetric extension, cropping.

/// A planar image of linear intensity: `channels` planes, each row-major
/// `height`×`width`, stored one after another (channel 0, then 1, …), the
/// layout the D-CNN's backends take (CHW). The simulator's input and
/// output, the runtime's frame and the display image are all this type.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    channels: usize,
    data: Vec<f32>,
}

impl Image {
    /// A black image with `channels` planes.
    pub fn zeros(width: usize, height: usize, channels: usize) -> Self {
        Self {
            width,
            height,
            channels,
            data: vec![0.0; channels * width * height],
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
            channels: planes.len(),
            data: planes.concat(),
        }
    }

    /// Builds an image from planar data (all of channel 0, then 1, …),
    /// checking its length.
    pub fn from_data(width: usize, height: usize, channels: usize, data: Vec<f32>) -> Self {
        assert_eq!(
            data.len(),
            channels * width * height,
            "planar data length mismatch"
        );
        Self {
            width,
            height,
            channels,
            data,
        }
    }

    /// An RGB image from planar data.
    pub fn rgb(width: usize, height: usize, data: Vec<f32>) -> Self {
        Self::from_data(width, height, 3, data)
    }

    pub fn channels(&self) -> usize {
        self.channels
    }

    /// All values, planar.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }

    pub fn into_data(self) -> Vec<f32> {
        self.data
    }

    /// Channel `c`, row-major.
    pub fn plane(&self, c: usize) -> &[f32] {
        let n = self.width * self.height;
        &self.data[c * n..(c + 1) * n]
    }

    pub fn plane_mut(&mut self, c: usize) -> &mut [f32] {
        let n = self.width * self.height;
        &mut self.data[c * n..(c + 1) * n]
    }

    /// The planes in channel order.
    pub fn planes(&self) -> impl ExactSizeIterator<Item = &[f32]> + '_ {
        let n = self.width * self.height;
        (0..self.channels).map(move |c| &self.data[c * n..(c + 1) * n])
    }

    pub fn planes_mut(&mut self) -> impl ExactSizeIterator<Item = &mut [f32]> + '_ {
        let n = (self.width * self.height).max(1);
        let channels = self.channels;
        let mut chunks = self.data.chunks_mut(n);
        (0..channels).map(move |_| chunks.next().unwrap_or_default())
    }

    /// A new image of the same size from a function of each plane.
    pub fn map_planes(&self, f: impl FnMut(&[f32]) -> Vec<f32>) -> Self {
        Self::from_planes(self.width, self.height, self.planes().map(f).collect())
    }

    /// up2: each pixel becomes a 2×2 block (the square pixel aperture on the retinal grid).
    pub fn up2(&self) -> Self {
        let (w, h) = (self.width, self.height);
        Self::from_planes(
            2 * w,
            2 * h,
            self.planes().map(|p| up2_plane(p, w, h)).collect(),
        )
    }

    /// Symmetric (half-sample, edge repeated) extension to `width`×`height`,
    /// the original at offset (`left`, `top`); repeats the mirroring as
    /// needed. The boundary rule of the optics' convolutions
    /// (docs/model.md §9), not a padding for networks ([`Image::pad_reflect`]).
    pub fn extend_symmetric(&self, left: usize, top: usize, width: usize, height: usize) -> Self {
        let planes = self
            .planes()
            .map(|p| extend_plane(p, self.width, self.height, left, top, width, height))
            .collect();
        Self::from_planes(width, height, planes)
    }

    /// Extends right and bottom to `width`×`height` by reflection about the
    /// last row and column (PyTorch's and ONNX's "reflect", what the trainer
    /// pads with), falling back to edge replication where the image is
    /// smaller than the pad. The one padding rule for a network that needs
    /// sides of a multiple; the result is cropped back with [`Image::crop`].
    pub fn pad_reflect(&self, width: usize, height: usize) -> Self {
        let index = |i: usize, n: usize| {
            if i < n {
                i
            } else if i - n + 1 < n {
                2 * (n - 1) - i
            } else {
                n - 1
            }
        };
        let mut data = Vec::with_capacity(self.channels * width * height);
        for p in self.planes() {
            for y in 0..height {
                let row = &p[index(y, self.height) * self.width..][..self.width];
                data.extend((0..width).map(|x| row[index(x, self.width)]));
            }
        }
        Self::from_data(width, height, self.channels, data)
    }

    /// The `width`×`height` block starting at (`left`, `top`).
    pub fn crop(&self, left: usize, top: usize, width: usize, height: usize) -> Self {
        assert!(
            left + width <= self.width && top + height <= self.height,
            "crop out of range"
        );
        let mut data = Vec::with_capacity(self.channels * width * height);
        for p in self.planes() {
            for y in top..top + height {
                data.extend_from_slice(&p[y * self.width + left..y * self.width + left + width]);
            }
        }
        Self::from_data(width, height, self.channels, data)
    }

    /// Clamps every value to [0, 1], the panel's range.
    pub fn clamped(mut self) -> Self {
        self.clamp_to_panel();
        self
    }

    /// Clamps every value to [0, 1] in place.
    pub fn clamp_to_panel(&mut self) {
        self.data.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
    }

    /// Mean of each plane.
    pub fn plane_means(&self) -> Vec<f64> {
        self.planes()
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

/// up2 of one `w`×`h` plane (see [`Image::up2`]).
pub fn up2_plane(p: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; 4 * w * h];
    for y in 0..2 * h {
        let src = &p[(y / 2) * w..(y / 2 + 1) * w];
        let dst = &mut out[y * 2 * w..(y + 1) * 2 * w];
        for (x, v) in src.iter().enumerate() {
            dst[2 * x] = *v;
            dst[2 * x + 1] = *v;
        }
    }
    out
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
            up.plane(0),
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
    fn pad_reflect_mirrors_about_the_last_row_and_column() {
        let im = Image::from_planes(3, 1, vec![vec![0.1, 0.2, 0.3]]);
        // Reflection skips the edge sample (…, 0.2, 0.3 | 0.2, 0.1), then
        // replicates once the frame is shorter than the pad.
        assert_eq!(im.pad_reflect(5, 1).data(), &[0.1, 0.2, 0.3, 0.2, 0.1]);
        assert_eq!(im.pad_reflect(6, 1).data(), &[0.1, 0.2, 0.3, 0.2, 0.1, 0.3]);
        let tall = Image::from_planes(1, 2, vec![vec![0.5, 0.7]]);
        assert_eq!(tall.pad_reflect(1, 3).data(), &[0.5, 0.7, 0.5]);
        assert_eq!(im.pad_reflect(5, 1).crop(0, 0, 3, 1), im);
    }

    #[test]
    fn planes_are_the_planar_data_in_channel_order() {
        let im = Image::from_planes(2, 1, vec![vec![1.0, 2.0], vec![3.0, 4.0]]);
        assert_eq!(im.data(), &[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(im.plane(1), &[3.0, 4.0]);
        assert_eq!(im.planes().count(), 2);
        let mut m = im.clone();
        for p in m.planes_mut() {
            p[0] = 0.0;
        }
        assert_eq!(m.data(), &[0.0, 2.0, 0.0, 4.0]);
    }

    #[test]
    fn crop_inverts_extension() {
        let im = Image::from_planes(3, 2, vec![vec![0.1, 0.2, 0.3, 0.4, 0.5, 0.6]]);
        assert_eq!(im.extend_symmetric(5, 4, 20, 11).crop(5, 4, 3, 2), im);
    }
}
