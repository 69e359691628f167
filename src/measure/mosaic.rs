//! A polarizer-mosaic frame (MODEL.md "On-chip polarizer mosaic") read as
//! the linear Stokes parameters of the light at each 2x2 cell: what a user
//! aiming a polarization camera wants to see (the total intensity, how
//! polarized the wall's light is and along which angle), at half resolution.
//!
//! Why cells and no interpolation: the live view shows the data, not a
//! demosaicing guess; the measurement never uses these images (it averages
//! each angle's own pixels, [`crate::scene::PixelMap::cell_frame`]).

use crate::scene::{Frame, MosaicLayout};

/// The Stokes images of a mosaic frame, one value per whole 2x2 cell.
#[derive(Debug, Clone, PartialEq)]
pub struct Stokes {
    /// `S0 = (I0 + I45 + I90 + I135) / 2`, the intensity without a polarizer.
    pub s0: Frame,
    /// Degree of linear polarization `sqrt(S1^2 + S2^2) / S0`, in [0, 1]
    /// (0 where `S0 <= 0`), with `S1 = I0 - I90`, `S2 = I45 - I135`.
    pub dolp: Frame,
    /// Angle of linear polarization `atan2(S2, S1) / 2`, degrees in
    /// [-90, 90] from the sensor's 0-degree micro-polarizer.
    pub aolp_deg: Frame,
}

/// The Stokes images of `frame`, whose first pixel sits at sensor column and
/// row `offset` behind a `layout` mosaic; cells start at the first pixel
/// with even sensor coordinates, and a frame narrower than one cell gives
/// empty images.
pub(crate) fn stokes(frame: &Frame, layout: MosaicLayout, offset: [u32; 2]) -> Stokes {
    let (x0, y0) = ((offset[0] % 2) as usize, (offset[1] % 2) as usize);
    let w = frame.width.saturating_sub(x0) / 2;
    let h = frame.height.saturating_sub(y0) / 2;
    let mut s0 = Frame::zeros(w, h);
    let mut dolp = Frame::zeros(w, h);
    let mut aolp = Frame::zeros(w, h);
    for cy in 0..h {
        for cx in 0..w {
            // I at 0, 45, 90, 135 degrees.
            let mut i = [0.0f64; 4];
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let (x, y) = (x0 + 2 * cx + dx, y0 + 2 * cy + dy);
                let k = layout.block_at(
                    i64::from(offset[0]) + x as i64,
                    i64::from(offset[1]) + y as i64,
                );
                i[k] = f64::from(frame.pixels[y * frame.width + x]);
            }
            let total = (i[0] + i[1] + i[2] + i[3]) / 2.0;
            let (s1, s2) = (i[0] - i[2], i[1] - i[3]);
            let p = cy * w + cx;
            s0.pixels[p] = total as f32;
            dolp.pixels[p] = if total > 0.0 {
                ((s1 * s1 + s2 * s2).sqrt() / total).min(1.0) as f32
            } else {
                0.0
            };
            aolp.pixels[p] = (0.5 * s2.atan2(s1)).to_degrees() as f32;
        }
    }
    Stokes {
        s0,
        dolp,
        aolp_deg: aolp,
    }
}

/// What a live view of a mosaic frame shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum View {
    /// The frame as read out: every pixel behind its own micro-polarizer.
    #[default]
    Raw,
    /// The intensity without a polarizer, `S0`.
    S0,
    /// The degree of linear polarization, 0 black to 1 white.
    Dolp,
    /// The angle of linear polarization, -90 degrees black to +90 white.
    Aolp,
    /// A colour camera's frame in colour: each whole 2x2 cell of its Bayer
    /// filter one RGB pixel (red, the mean of the greens, blue).
    Colour,
}

/// `view` of a raw mosaic frame (`pixels`, `width` x `height`, `bits`
/// significant) as 16-bit values with their significant bits: the Stokes
/// images at half resolution (`S0` on the frame's scale, one bit more;
/// DoLP and AoLP over the full 16 bits), or the frame itself for `Raw`.
pub fn view(
    pixels: &[u16],
    (width, height, bits): (usize, usize, u32),
    layout: MosaicLayout,
    offset: [u32; 2],
    view: View,
) -> (usize, usize, Vec<u16>, u32) {
    if view == View::Raw {
        return (width, height, pixels.to_vec(), bits);
    }
    let frame = Frame {
        width,
        height,
        pixels: pixels.iter().map(|&p| f32::from(p)).collect(),
    };
    let s = stokes(&frame, layout, offset);
    let (image, scale, shift, bits): (&Frame, f32, f32, u32) = match view {
        View::S0 | View::Raw | View::Colour => (&s.s0, 1.0, 0.0, (bits + 1).min(16)),
        View::Dolp => (&s.dolp, 65535.0, 0.0, 16),
        View::Aolp => (&s.aolp_deg, 65535.0 / 180.0, 90.0, 16),
    };
    let out = image
        .pixels
        .iter()
        .map(|&v| ((v + shift) * scale).round().clamp(0.0, 65535.0) as u16)
        .collect();
    (image.width, image.height, out, bits)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mosaic frame of light polarized at `aolp` degrees, degree `p`,
    /// intensity `s0`: each pixel `s0/2 (1 + p cos 2(theta - aolp))`.
    fn frame(width: usize, height: usize, offset: [u32; 2], s0: f64, p: f64, aolp: f64) -> Frame {
        let mut f = Frame::zeros(width, height);
        for y in 0..height {
            for x in 0..width {
                let theta = MosaicLayout::Polarsens.degrees_at(
                    i64::from(offset[0]) + x as i64,
                    i64::from(offset[1]) + y as i64,
                );
                f.pixels[y * width + x] =
                    (s0 / 2.0 * (1.0 + p * (2.0 * (theta - aolp)).to_radians().cos())) as f32;
            }
        }
        f
    }

    #[test]
    fn polarized_light_reads_back_its_intensity_degree_and_angle() {
        for offset in [[0, 0], [1, 0], [0, 1], [3, 5]] {
            let s = stokes(
                &frame(9, 7, offset, 100.0, 0.6, 30.0),
                MosaicLayout::Polarsens,
                offset,
            );
            assert_eq!((s.s0.width, s.s0.height), (4, 3), "{offset:?}");
            for k in 0..s.s0.pixels.len() {
                assert!((s.s0.pixels[k] - 100.0).abs() < 1e-3, "{offset:?}");
                assert!((s.dolp.pixels[k] - 0.6).abs() < 1e-5, "{offset:?}");
                assert!((s.aolp_deg.pixels[k] - 30.0).abs() < 1e-3, "{offset:?}");
            }
        }
        let dark = stokes(&Frame::zeros(4, 4), MosaicLayout::Polarsens, [0, 0]);
        assert!(dark.dolp.pixels.iter().all(|&v| v == 0.0));
        let tiny = stokes(&Frame::zeros(1, 1), MosaicLayout::Polarsens, [0, 0]);
        assert!(tiny.s0.pixels.is_empty());
    }

    #[test]
    fn views_map_the_stokes_images_onto_16_bits() {
        let f = frame(4, 4, [0, 0], 1000.0, 0.5, 45.0);
        let raw: Vec<u16> = f.pixels.iter().map(|&v| v.round() as u16).collect();
        let dims = (4, 4, 12);
        let (w, h, px, bits) = view(&raw, dims, MosaicLayout::Polarsens, [0, 0], View::Raw);
        assert_eq!((w, h, px, bits), (4, 4, raw.clone(), 12));
        let (w, h, px, bits) = view(&raw, dims, MosaicLayout::Polarsens, [0, 0], View::S0);
        assert_eq!((w, h, bits), (2, 2, 13));
        assert!(px.iter().all(|&v| v.abs_diff(1000) <= 1), "{px:?}");
        let (_, _, px, _) = view(&raw, dims, MosaicLayout::Polarsens, [0, 0], View::Dolp);
        assert!(px.iter().all(|&v| v.abs_diff(32768) <= 70), "{px:?}");
        let (_, _, px, _) = view(&raw, dims, MosaicLayout::Polarsens, [0, 0], View::Aolp);
        // 45 degrees: three quarters of the way from -90 to 90.
        assert!(px.iter().all(|&v| v.abs_diff(49151) <= 70), "{px:?}");
    }
}
