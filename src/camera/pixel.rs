//! The pixel formats polnlos reads: each one's GenICam name, bit depth and
//! decoding of a camera buffer, in one place, so a new format (a packed one
//! such as Mono12p) is one variant here and a format polnlos cannot decode
//! is an error rather than a mis-read frame.

use serde::{Deserialize, Serialize};

/// Monochrome pixel formats polnlos reads.
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
    pub const ALL: [PixelFormat; 4] = [
        PixelFormat::Mono8,
        PixelFormat::Mono12,
        PixelFormat::Mono12p,
        PixelFormat::Mono16,
    ];

    /// The GenICam name.
    pub fn name(self) -> &'static str {
        match self {
            PixelFormat::Mono8 => "Mono8",
            PixelFormat::Mono12 => "Mono12",
            PixelFormat::Mono12p => "Mono12p",
            PixelFormat::Mono16 => "Mono16",
        }
    }

    /// Significant bits.
    pub fn bits(self) -> u32 {
        match self {
            PixelFormat::Mono8 => 8,
            PixelFormat::Mono12 | PixelFormat::Mono12p => 12,
            PixelFormat::Mono16 => 16,
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
        match self {
            PixelFormat::Mono8 => Some(pixels),
            PixelFormat::Mono12 | PixelFormat::Mono16 => pixels.checked_mul(2),
            PixelFormat::Mono12p => pixels.checked_mul(3).map(|b| b.div_ceil(2)),
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
        Ok(match self {
            PixelFormat::Mono8 => data.iter().map(|&b| u16::from(b)).collect(),
            PixelFormat::Mono12 | PixelFormat::Mono16 => data
                .chunks_exact(2)
                .map(|p| u16::from_le_bytes([p[0], p[1]]))
                .collect(),
            PixelFormat::Mono12p => {
                let mut out = Vec::with_capacity(pixels);
                for c in data.chunks(3) {
                    let b = |k: usize| u16::from(c.get(k).copied().unwrap_or(0));
                    out.push(b(0) | (b(1) & 0x0f) << 8);
                    out.push(b(1) >> 4 | b(2) << 4);
                }
                out.truncate(pixels);
                out
            }
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
        assert_eq!(PixelFormat::names(), "Mono8, Mono12, Mono12p, Mono16");
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
    }
}
