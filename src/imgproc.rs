//! Image containers shared by the camera, renderer and tracker.
//!
//! `Image<T>` is a dense, row-major, tightly packed image. Buffers are sized
//! once and reused: the hot paths write into an existing `Image` and never
//! reallocate it.

/// A dense row-major image. `data.len() == width * height` always holds.
#[derive(Debug, Clone, PartialEq)]
pub struct Image<T> {
    width: usize,
    height: usize,
    data: Vec<T>,
}

/// Gray intensity image (0..=255 scale) as floats.
pub type ImageF32 = Image<f32>;
/// 8-bit gray image, as cameras deliver it.
pub type ImageU8 = Image<u8>;

impl<T: Copy> Image<T> {
    /// An image filled with `value`.
    pub fn new(width: usize, height: usize, value: T) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    /// Wraps `data`; `None` when its length is not `width * height`.
    pub fn from_vec(width: usize, height: usize, data: Vec<T>) -> Option<Self> {
        (data.len() == width * height).then_some(Self {
            width,
            height,
            data,
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// All pixels, row-major.
    pub fn data(&self) -> &[T] {
        &self.data
    }

    /// All pixels, row-major, mutable.
    pub fn data_mut(&mut self) -> &mut [T] {
        &mut self.data
    }

    /// Consumes the image and returns its pixels.
    pub fn into_vec(self) -> Vec<T> {
        self.data
    }

    /// Pixel at `(x, y)`, or `None` outside the image.
    pub fn get(&self, x: usize, y: usize) -> Option<T> {
        if x < self.width && y < self.height {
            self.data.get(y * self.width + x).copied()
        } else {
            None
        }
    }

    /// One row.
    pub fn row(&self, y: usize) -> &[T] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// One row, mutable.
    pub fn row_mut(&mut self, y: usize) -> &mut [T] {
        &mut self.data[y * self.width..(y + 1) * self.width]
    }

    /// Sets every pixel to `value` without reallocating.
    pub fn fill(&mut self, value: T) {
        self.data.fill(value);
    }

    /// Resizes in place, reusing the allocation when it is large enough.
    pub fn resize(&mut self, width: usize, height: usize, value: T) {
        self.width = width;
        self.height = height;
        self.data.clear();
        self.data.resize(width * height, value);
    }
}

impl Image<f32> {
    /// Bilinear interpolation at `(x, y)` with pixel centers at integers.
    /// `None` unless all four neighbours are inside the image.
    #[inline(always)]
    pub fn bilinear(&self, x: f32, y: f32) -> Option<f32> {
        // Compared as floats before any cast: a huge coordinate (a point
        // just in front of the camera plane) would saturate the cast and
        // wrap `x0 + 1` past the bounds check.
        let (max_x, max_y) = (
            self.width.saturating_sub(1) as f32,
            self.height.saturating_sub(1) as f32,
        );
        if !(x >= 0.0 && y >= 0.0 && x < max_x && y < max_y) {
            return None;
        }
        let x0 = x as usize;
        let y0 = y as usize;
        if x0 + 1 >= self.width || y0 + 1 >= self.height {
            return None;
        }
        let fx = x - x0 as f32;
        let fy = y - y0 as f32;
        let i = y0 * self.width + x0;
        let d = &self.data;
        let top = d[i] + fx * (d[i + 1] - d[i]);
        let bottom = d[i + self.width] + fx * (d[i + self.width + 1] - d[i + self.width]);
        Some(top + fy * (bottom - top))
    }

    /// Converts into an 8-bit image, rounding and clamping.
    pub fn to_u8(&self) -> ImageU8 {
        Image {
            width: self.width,
            height: self.height,
            data: self
                .data
                .iter()
                .map(|&v| v.round().clamp(0.0, 255.0) as u8)
                .collect(),
        }
    }
}

impl Image<u8> {
    /// Converts into a float image on the same 0..=255 scale.
    pub fn to_f32(&self) -> ImageF32 {
        Image {
            width: self.width,
            height: self.height,
            data: self.data.iter().map(|&v| v as f32).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_refuses_huge_and_non_finite_coordinates() {
        let img = Image::from_vec(3, 3, vec![1.0; 9]).expect("3x3");
        for (x, y) in [
            (1e30, 1.0),
            (1.0, 1e30),
            (f32::INFINITY, 1.0),
            (f32::NAN, 1.0),
            (1.0, f32::MAX),
            (2.0, 1.0),
        ] {
            assert_eq!(img.bilinear(x, y), None, "({x}, {y})");
        }
        assert_eq!(img.bilinear(1.5, 1.5), Some(1.0));
    }

    #[test]
    fn bilinear_uses_integer_pixel_centers() {
        let img = Image::from_vec(2, 2, vec![0.0, 10.0, 20.0, 30.0]).expect("2x2");
        assert_eq!(img.bilinear(0.0, 0.0), Some(0.0));
        assert_eq!(img.bilinear(0.5, 0.0), Some(5.0));
        assert_eq!(img.bilinear(0.5, 0.5), Some(15.0));
        assert_eq!(img.bilinear(1.0, 0.0), None, "needs the right neighbour");
        assert_eq!(img.bilinear(-0.1, 0.0), None);
        assert_eq!(img.bilinear(f32::NAN, 0.0), None);
    }

    #[test]
    fn from_vec_checks_length() {
        assert!(Image::from_vec(3, 2, vec![0u8; 5]).is_none());
        assert!(Image::from_vec(3, 2, vec![0u8; 6]).is_some());
    }
}
