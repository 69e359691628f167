//! The pixel formats polnlos reads: each one's GenICam name, bit depth,
//! buffer layout and whether its sensor is a polarizer mosaic, in one place,
//! so a new format (a vendor's name for a known layout) is one variant here
//! and a format polnlos cannot decode is an error rather than a mis-read frame.
//!
//! Polarization cameras (Sony IMX250MZR/IMX253MZR "Polarsens") present
//! their raw mosaic under vendor names Aravis does not know; polnlos sets
//! them by name and unpacks the buffer itself. Names and layouts: Lucid
//! Arena SDK `ArenaCDefs.h` (`PolarizeMono8` 0x81080001, `PolarizeMono12p`
//! 0x810C0047, `PolarizeMono12Packed` 0x810C0006, `PolarizeMono12`
//! 0x81100008, `PolarizeMono16` 0x81100007), The Imaging Source's tiscamera
//! (`PolarizedMono8` 0x8108000A, `PolarizedMono12p` 0x810C000B,
//! `PolarizedMono12Packed` 0x810C0010, `PolarizedMono16` 0x8110000C), FLIR
//! Spinnaker's names (`Polarized8`, `Polarized12p`, `Polarized16`; their
//! device values are not published, and polnlos needs only the name).

use serde::{Deserialize, Serialize};

use crate::measure::colour::BayerPattern;
use crate::scene::MosaicLayout;

/// Pixel formats polnlos reads: monochrome, and the raw mosaic of
/// polarization cameras under each vendor's name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
pub enum PixelFormat {
    /// 8 bits.
    Mono8,
    /// 12 bits in 16-bit little-endian words.
    Mono12,
    /// 12 bits packed, two pixels in three bytes (GenICam PFNC `Mono12p`:
    /// least significant bits first).
    Mono12p,
    /// 16 bits, little-endian.
    Mono16,
    /// Lucid: Polarsens mosaic, 8 bits.
    PolarizeMono8,
    /// Lucid: Polarsens mosaic, 12 bits in 16-bit words.
    PolarizeMono12,
    /// Lucid: Polarsens mosaic, 12 bits packed as `Mono12p`.
    PolarizeMono12p,
    /// Lucid: Polarsens mosaic, 12 bits packed as GigE Vision `Mono12Packed`.
    PolarizeMono12Packed,
    /// Lucid: Polarsens mosaic, 16 bits.
    PolarizeMono16,
    /// The Imaging Source: Polarsens mosaic, 8 bits.
    PolarizedMono8,
    /// The Imaging Source: Polarsens mosaic, 12 bits packed as `Mono12p` (USB3 Vision).
    PolarizedMono12p,
    /// The Imaging Source: Polarsens mosaic, 12 bits as `Mono12Packed` (GigE Vision).
    PolarizedMono12Packed,
    /// The Imaging Source: Polarsens mosaic, 16 bits.
    PolarizedMono16,
    /// FLIR: Polarsens mosaic, 8 bits.
    Polarized8,
    /// FLIR: Polarsens mosaic, 12 bits packed as `Mono12p`.
    Polarized12p,
    /// FLIR: Polarsens mosaic, 16 bits.
    Polarized16,
    /// Bayer RG colour filter, raw, 8 bits.
    BayerRG8,
    /// Bayer RG colour filter, raw, 10 bits in 16-bit little-endian words.
    BayerRG10,
    /// Bayer RG colour filter, raw, 12 bits in 16-bit little-endian words.
    BayerRG12,
    /// Bayer RG colour filter, raw, 16 bits, little-endian.
    BayerRG16,
    /// Bayer GR colour filter, raw, 8 bits.
    BayerGR8,
    /// Bayer GR colour filter, raw, 10 bits in 16-bit little-endian words.
    BayerGR10,
    /// Bayer GR colour filter, raw, 12 bits in 16-bit little-endian words.
    BayerGR12,
    /// Bayer GR colour filter, raw, 16 bits, little-endian.
    BayerGR16,
    /// Bayer GB colour filter, raw, 8 bits.
    BayerGB8,
    /// Bayer GB colour filter, raw, 10 bits in 16-bit little-endian words.
    BayerGB10,
    /// Bayer GB colour filter, raw, 12 bits in 16-bit little-endian words.
    BayerGB12,
    /// Bayer GB colour filter, raw, 16 bits, little-endian.
    BayerGB16,
    /// Bayer BG colour filter, raw, 8 bits.
    BayerBG8,
    /// Bayer BG colour filter, raw, 10 bits in 16-bit little-endian words.
    BayerBG10,
    /// Bayer BG colour filter, raw, 12 bits in 16-bit little-endian words.
    BayerBG12,
    /// Bayer BG colour filter, raw, 16 bits, little-endian.
    BayerBG16,
}

/// How a format lays its pixels out in a buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// One byte per pixel.
    Bits8,
    /// 10 significant bits in 16-bit little-endian words.
    Bits10In16,
    /// 12 significant bits in 16-bit little-endian words.
    Bits12In16,
    /// Two pixels in three bytes, least significant bits first (PFNC `Mono12p`):
    /// `p0 = b0 | (b1 & 0x0f) << 8`, `p1 = b1 >> 4 | b2 << 4`.
    Packed12p,
    /// Two pixels in three bytes, GigE Vision `Mono12Packed`:
    /// `p0 = b0 << 4 | (b1 & 0x0f)`, `p1 = b2 << 4 | b1 >> 4`.
    Packed12GigE,
    /// 16-bit little-endian words.
    Bits16,
}

/// A buffer that does not hold the frame its format and size say.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("a {width}x{height} {format} frame needs {needed} bytes, the buffer holds {got}")]
pub struct DecodeError {
    /// The format's name.
    pub format: &'static str,
    /// Frame width, pixels.
    pub width: usize,
    /// Frame height, pixels.
    pub height: usize,
    /// Bytes the frame needs (`None` past `usize`).
    pub needed: Needed,
    /// Bytes the buffer holds.
    pub got: usize,
}

/// Bytes a frame needs, or that the count overflows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Needed(pub Option<usize>);

impl std::fmt::Display for Needed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.0 {
            Some(n) => write!(f, "{n}"),
            None => f.write_str("more than the address space"),
        }
    }
}

impl PixelFormat {
    /// Every format polnlos reads, in the order errors list them.
    pub const ALL: [PixelFormat; 32] = [
        PixelFormat::Mono8,
        PixelFormat::Mono12,
        PixelFormat::Mono12p,
        PixelFormat::Mono16,
        PixelFormat::PolarizeMono8,
        PixelFormat::PolarizeMono12,
        PixelFormat::PolarizeMono12p,
        PixelFormat::PolarizeMono12Packed,
        PixelFormat::PolarizeMono16,
        PixelFormat::PolarizedMono8,
        PixelFormat::PolarizedMono12p,
        PixelFormat::PolarizedMono12Packed,
        PixelFormat::PolarizedMono16,
        PixelFormat::Polarized8,
        PixelFormat::Polarized12p,
        PixelFormat::Polarized16,
        PixelFormat::BayerRG8,
        PixelFormat::BayerRG10,
        PixelFormat::BayerRG12,
        PixelFormat::BayerRG16,
        PixelFormat::BayerGR8,
        PixelFormat::BayerGR10,
        PixelFormat::BayerGR12,
        PixelFormat::BayerGR16,
        PixelFormat::BayerGB8,
        PixelFormat::BayerGB10,
        PixelFormat::BayerGB12,
        PixelFormat::BayerGB16,
        PixelFormat::BayerBG8,
        PixelFormat::BayerBG10,
        PixelFormat::BayerBG12,
        PixelFormat::BayerBG16,
    ];

    /// The GenICam name.
    pub fn name(self) -> &'static str {
        match self {
            PixelFormat::Mono8 => "Mono8",
            PixelFormat::Mono12 => "Mono12",
            PixelFormat::Mono12p => "Mono12p",
            PixelFormat::Mono16 => "Mono16",
            PixelFormat::PolarizeMono8 => "PolarizeMono8",
            PixelFormat::PolarizeMono12 => "PolarizeMono12",
            PixelFormat::PolarizeMono12p => "PolarizeMono12p",
            PixelFormat::PolarizeMono12Packed => "PolarizeMono12Packed",
            PixelFormat::PolarizeMono16 => "PolarizeMono16",
            PixelFormat::PolarizedMono8 => "PolarizedMono8",
            PixelFormat::PolarizedMono12p => "PolarizedMono12p",
            PixelFormat::PolarizedMono12Packed => "PolarizedMono12Packed",
            PixelFormat::PolarizedMono16 => "PolarizedMono16",
            PixelFormat::Polarized8 => "Polarized8",
            PixelFormat::Polarized12p => "Polarized12p",
            PixelFormat::Polarized16 => "Polarized16",
            PixelFormat::BayerRG8 => "BayerRG8",
            PixelFormat::BayerRG10 => "BayerRG10",
            PixelFormat::BayerRG12 => "BayerRG12",
            PixelFormat::BayerRG16 => "BayerRG16",
            PixelFormat::BayerGR8 => "BayerGR8",
            PixelFormat::BayerGR10 => "BayerGR10",
            PixelFormat::BayerGR12 => "BayerGR12",
            PixelFormat::BayerGR16 => "BayerGR16",
            PixelFormat::BayerGB8 => "BayerGB8",
            PixelFormat::BayerGB10 => "BayerGB10",
            PixelFormat::BayerGB12 => "BayerGB12",
            PixelFormat::BayerGB16 => "BayerGB16",
            PixelFormat::BayerBG8 => "BayerBG8",
            PixelFormat::BayerBG10 => "BayerBG10",
            PixelFormat::BayerBG12 => "BayerBG12",
            PixelFormat::BayerBG16 => "BayerBG16",
        }
    }

    /// How its pixels lie in a buffer.
    pub fn layout(self) -> Layout {
        use PixelFormat::*;
        match self {
            Mono8 | PolarizeMono8 | PolarizedMono8 | Polarized8 => Layout::Bits8,
            BayerRG8 | BayerGR8 | BayerGB8 | BayerBG8 => Layout::Bits8,
            BayerRG10 | BayerGR10 | BayerGB10 | BayerBG10 => Layout::Bits10In16,
            Mono12 | PolarizeMono12 => Layout::Bits12In16,
            BayerRG12 | BayerGR12 | BayerGB12 | BayerBG12 => Layout::Bits12In16,
            Mono12p | PolarizeMono12p | PolarizedMono12p | Polarized12p => Layout::Packed12p,
            PolarizeMono12Packed | PolarizedMono12Packed => Layout::Packed12GigE,
            Mono16 | PolarizeMono16 | PolarizedMono16 | Polarized16 => Layout::Bits16,
            BayerRG16 | BayerGR16 | BayerGB16 | BayerBG16 => Layout::Bits16,
        }
    }

    /// The micro-polarizer pattern of the sensor the format reads out raw,
    /// `None` for a plain monochrome sensor (every vendor's is Sony's Polarsens).
    pub fn mosaic(self) -> Option<MosaicLayout> {
        use PixelFormat::*;
        match self {
            PolarizeMono8
            | PolarizeMono12
            | PolarizeMono12p
            | PolarizeMono12Packed
            | PolarizeMono16
            | PolarizedMono8
            | PolarizedMono12p
            | PolarizedMono12Packed
            | PolarizedMono16
            | Polarized8
            | Polarized12p
            | Polarized16 => Some(MosaicLayout::Polarsens),
            _ => None,
        }
    }

    /// The Bayer filter of a colour sensor the format reads out raw, `None`
    /// for a sensor without one.
    pub fn bayer(self) -> Option<BayerPattern> {
        use PixelFormat::*;
        match self {
            BayerRG8 | BayerRG10 | BayerRG12 | BayerRG16 => Some(BayerPattern::RG),
            BayerGR8 | BayerGR10 | BayerGR12 | BayerGR16 => Some(BayerPattern::GR),
            BayerGB8 | BayerGB10 | BayerGB12 | BayerGB16 => Some(BayerPattern::GB),
            BayerBG8 | BayerBG10 | BayerBG12 | BayerBG16 => Some(BayerPattern::BG),
            _ => None,
        }
    }

    /// The polarizer mosaic of a camera offering `offered` (GenICam names)
    /// and using `current`: a camera that offers a polarization format has
    /// the mosaic whatever it reads out now.
    pub fn sensor_mosaic(offered: &[String], current: PixelFormat) -> Option<MosaicLayout> {
        offered
            .iter()
            .filter_map(|n| PixelFormat::from_name(n))
            .chain([current])
            .find_map(PixelFormat::mosaic)
    }

    /// Significant bits.
    pub fn bits(self) -> u32 {
        match self.layout() {
            Layout::Bits8 => 8,
            Layout::Bits10In16 => 10,
            Layout::Bits12In16 | Layout::Packed12p | Layout::Packed12GigE => 12,
            Layout::Bits16 => 16,
        }
    }

    /// The format of a GenICam name (as [`PixelFormat::name`] writes it).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.name() == name)
    }

    /// Every name, comma-separated (for messages).
    pub fn names() -> String {
        Self::ALL.map(Self::name).join(", ")
    }

    /// Largest digital number, `2^bits - 1`.
    pub fn full_scale(self) -> f64 {
        f64::from((1u32 << self.bits()) - 1)
    }

    /// Bytes a `width x height` frame takes, `None` when the count overflows.
    pub fn frame_bytes(self, width: usize, height: usize) -> Option<usize> {
        let pixels = width.checked_mul(height)?;
        match self.layout() {
            Layout::Bits8 => Some(pixels),
            Layout::Bits10In16 | Layout::Bits12In16 | Layout::Bits16 => pixels.checked_mul(2),
            Layout::Packed12p | Layout::Packed12GigE => {
                pixels.checked_mul(3).map(|b| b.div_ceil(2))
            }
        }
    }

    /// The pixels of a `width x height` frame in `data` (row-major, no
    /// padding; bytes past the frame are ignored), widened to 16 bits.
    pub fn decode(self, data: &[u8], width: usize, height: usize) -> Result<Vec<u16>, DecodeError> {
        let needed = self.frame_bytes(width, height);
        let data = match needed {
            Some(n) if n <= data.len() => &data[..n],
            _ => {
                return Err(DecodeError {
                    format: self.name(),
                    width,
                    height,
                    needed: Needed(needed),
                    got: data.len(),
                })
            }
        };
        let pixels = width * height;
        let unpack = |pair: fn(u16, u16, u16) -> (u16, u16)| {
            let mut out = Vec::with_capacity(pixels + 1);
            for c in data.chunks(3) {
                let b = |k: usize| u16::from(c.get(k).copied().unwrap_or(0));
                let (p0, p1) = pair(b(0), b(1), b(2));
                out.push(p0);
                out.push(p1);
            }
            out.truncate(pixels);
            out
        };
        Ok(match self.layout() {
            Layout::Bits8 => data.iter().map(|&b| u16::from(b)).collect(),
            Layout::Bits10In16 | Layout::Bits12In16 | Layout::Bits16 => data
                .chunks_exact(2)
                .map(|p| u16::from_le_bytes([p[0], p[1]]))
                .collect(),
            Layout::Packed12p => unpack(|b0, b1, b2| (b0 | (b1 & 0x0f) << 8, b1 >> 4 | b2 << 4)),
            Layout::Packed12GigE => unpack(|b0, b1, b2| (b0 << 4 | (b1 & 0x0f), b2 << 4 | b1 >> 4)),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn names_round_trip_and_unknown_ones_are_none() {
        for f in PixelFormat::ALL {
            assert_eq!(PixelFormat::from_name(f.name()), Some(f));
        }
        assert_eq!(PixelFormat::from_name("Mono10"), None);
        assert!(PixelFormat::names().starts_with("Mono8, Mono12, Mono12p, Mono16, PolarizeMono8"));
        assert_eq!(PixelFormat::Mono16.mosaic(), None);
        for f in ["PolarizeMono8", "PolarizedMono16", "Polarized12p"] {
            let f = PixelFormat::from_name(f).unwrap();
            assert_eq!(f.mosaic(), Some(MosaicLayout::Polarsens), "{f:?}");
        }
        assert_eq!(PixelFormat::PolarizeMono12Packed.bits(), 12);
        // Aravis's Bayer names: a colour filter, no polarizer mosaic.
        for (name, pattern, bits) in [
            ("BayerRG8", BayerPattern::RG, 8),
            ("BayerGR10", BayerPattern::GR, 10),
            ("BayerGB12", BayerPattern::GB, 12),
            ("BayerBG16", BayerPattern::BG, 16),
        ] {
            let f = PixelFormat::from_name(name).unwrap();
            assert_eq!(
                (f.bayer(), f.mosaic(), f.bits()),
                (Some(pattern), None, bits)
            );
        }
        assert_eq!(PixelFormat::Mono12.bayer(), None);
        assert_eq!(PixelFormat::Polarized16.bayer(), None);
        assert_eq!(PixelFormat::BayerRG10.full_scale(), 1023.0);
        assert_eq!(
            PixelFormat::BayerRG10.decode(&[0xff, 0x03, 0x01, 0x00], 2, 1),
            Ok(vec![1023, 1])
        );
    }

    #[test]
    fn decodes_each_layout() {
        assert_eq!(
            PixelFormat::Mono8.decode(&[1, 255, 7], 2, 1),
            Ok(vec![1, 255])
        );
        assert_eq!(
            PixelFormat::Mono16.decode(&[0x34, 0x12, 0xff, 0xff], 2, 1),
            Ok(vec![0x1234, 0xffff])
        );
        // Mono12p: 0xABC and 0x123 as BC 3A 12 (low bits first).
        assert_eq!(
            PixelFormat::Mono12p.decode(&[0xbc, 0x3a, 0x12], 2, 1),
            Ok(vec![0xabc, 0x123])
        );
        // Mono12Packed (GigE Vision): 0xABC and 0x123 as AB 3C 12.
        assert_eq!(
            PixelFormat::PolarizedMono12Packed.decode(&[0xab, 0x3c, 0x12], 2, 1),
            Ok(vec![0xabc, 0x123])
        );
        assert_eq!(
            PixelFormat::PolarizeMono12p.decode(&[0xbc, 0x3a, 0x12], 2, 1),
            Ok(vec![0xabc, 0x123])
        );
        // An odd pixel count ends in a half-filled triple: 2 bytes.
        assert_eq!(
            PixelFormat::Mono12p.decode(&[0xbc, 0x3a, 0x12, 0xff, 0x0f], 3, 1),
            Ok(vec![0xabc, 0x123, 0xfff])
        );
    }

    #[test]
    fn short_and_overflowing_buffers_are_errors() {
        let e = PixelFormat::Mono16.decode(&[0; 7], 2, 2).unwrap_err();
        assert_eq!((e.needed, e.got), (Needed(Some(8)), 7));
        assert!(
            e.to_string().contains("2x2 Mono16 frame needs 8 bytes"),
            "{e}"
        );
        let e = PixelFormat::Mono8
            .decode(&[0; 4], usize::MAX, 2)
            .unwrap_err();
        assert_eq!(e.needed, Needed(None));
    }

    proptest! {
        #[test]
        fn mono12p_packs_back_to_what_it_decoded(px in proptest::collection::vec(0u16..4096, 1..64)) {
            let mut packed = Vec::new();
            for pair in px.chunks(2) {
                let (a, b) = (pair[0], pair.get(1).copied().unwrap_or(0));
                packed.push((a & 0xff) as u8);
                packed.push(((a >> 8) | (b & 0x0f) << 4) as u8);
                if pair.len() == 2 {
                    packed.push((b >> 4) as u8);
                }
            }
            prop_assert_eq!(PixelFormat::Mono12p.decode(&packed, px.len(), 1), Ok(px));
        }

        #[test]
        fn mono12packed_packs_back_to_what_it_decoded(px in proptest::collection::vec(0u16..4096, 1..64)) {
            let mut packed = Vec::new();
            for pair in px.chunks(2) {
                let (a, b) = (pair[0], pair.get(1).copied().unwrap_or(0));
                packed.push((a >> 4) as u8);
                packed.push(((a & 0x0f) | (b & 0x0f) << 4) as u8);
                if pair.len() == 2 {
                    packed.push((b >> 4) as u8);
                }
            }
            prop_assert_eq!(PixelFormat::PolarizeMono12Packed.decode(&packed, px.len(), 1), Ok(px));
        }
    }
}
