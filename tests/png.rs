//! PNG bytes as the tests read them back: size, samples a pixel, bit depth
//! and the samples, through the `png` crate (the decoder polnlos uses, not
//! polnlos's own code).

/// A decoded PNG.
pub struct Png {
    pub width: usize,
    pub height: usize,
    /// Samples a pixel: 1 grey, 3 RGB.
    pub channels: usize,
    pub bits: u32,
    /// Samples, row-major, top row first.
    pub samples: Vec<u16>,
}

impl Png {
    /// The sample of channel `c` at column `x`, row `y`.
    pub fn at(&self, x: usize, y: usize, c: usize) -> u16 {
        self.samples[(y * self.width + x) * self.channels + c]
    }

    /// Grey samples of a grey image.
    pub fn grey(&self) -> &[u16] {
        assert_eq!(self.channels, 1, "a grey PNG");
        &self.samples
    }
}

/// Decodes PNG bytes (8- or 16-bit), panicking when they are not a PNG.
pub fn decode(bytes: &[u8]) -> Png {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .expect("a PNG header");
    let mut buf = vec![0u8; reader.output_buffer_size().expect("a size")];
    let info = reader.next_frame(&mut buf).expect("PNG pixels");
    buf.truncate(info.buffer_size());
    let samples = match info.bit_depth {
        png::BitDepth::Sixteen => buf
            .chunks_exact(2)
            .map(|b| u16::from_be_bytes([b[0], b[1]]))
            .collect(),
        png::BitDepth::Eight => buf.iter().map(|&b| u16::from(b)).collect(),
        d => panic!("{d:?}-bit PNG"),
    };
    Png {
        width: info.width as usize,
        height: info.height as usize,
        channels: info.color_type.samples(),
        bits: info.bit_depth as u32,
        samples,
    }
}

/// Decodes a PNG file.
pub fn open(path: &std::path::Path) -> Png {
    decode(&std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())))
}
