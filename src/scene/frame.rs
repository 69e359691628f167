//! A single-channel camera frame in floating point (digital numbers, DN).
//!
//! Why here, beside the frame geometry: simulation renders frames and
//! measurement samples them, so both name it from below.

/// A monochrome frame, row-major, top row first; pixel centres at integer
/// coordinates (MODEL.md "From camera frames to i").
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Pixel values (DN, dark-subtracted where that applies).
    pub pixels: Vec<f32>,
}

impl Frame {
    /// A black frame.
    pub fn zeros(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            pixels: vec![0.0; width * height],
        }
    }

    /// Bilinear sample at (x, y); `None` outside `[0, w-1] x [0, h-1]`.
    pub fn bilinear(&self, x: f64, y: f64) -> Option<f64> {
        if !(x >= 0.0 && y >= 0.0 && x <= (self.width - 1) as f64 && y <= (self.height - 1) as f64)
        {
            return None;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let p = |xx: usize, yy: usize| f64::from(self.pixels[yy * self.width + xx]);
        let top = p(x0, y0) * (1.0 - fx) + p(x1, y0) * fx;
        let bottom = p(x0, y1) * (1.0 - fx) + p(x1, y1) * fx;
        Some(top * (1.0 - fy) + bottom * fy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_centres_and_edges() {
        let f = Frame {
            width: 2,
            height: 2,
            pixels: vec![0.0, 1.0, 2.0, 3.0],
        };
        assert_eq!(f.bilinear(0.0, 0.0), Some(0.0));
        assert_eq!(f.bilinear(1.0, 1.0), Some(3.0));
        assert_eq!(f.bilinear(0.5, 0.5), Some(1.5));
        assert_eq!(f.bilinear(0.25, 0.0), Some(0.25));
        assert_eq!(f.bilinear(1.01, 0.0), None);
        assert_eq!(f.bilinear(-0.01, 0.0), None);
        assert_eq!(f.bilinear(f64::NAN, 0.0), None);
    }
}
