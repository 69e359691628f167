//! NumPy `.npy` arrays (C order) of f64 or f32, through the `npyz` crate.

use std::path::Path;

use npyz::WriterBuilder;

use super::FileError;

/// An array read from a `.npy` file: its shape and its values in C order.
#[derive(Debug, Clone, PartialEq)]
pub struct Array {
    /// Shape, outermost first.
    pub shape: Vec<usize>,
    /// Values in C (row-major) order.
    pub data: Vec<f64>,
    /// Bits of an unsigned integer dtype (8 for `u1`, 16 for `u2`), else
    /// None. Why: an image stored as integers has its full scale there.
    pub unsigned_bits: Option<u32>,
}

fn encode<T: npyz::AutoSerialize + Copy>(shape: &[usize], data: &[T]) -> std::io::Result<Vec<u8>> {
    let mut buf = Vec::new();
    let shape: Vec<u64> = shape.iter().map(|&s| s as u64).collect();
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&shape)
        .writer(&mut buf)
        .begin_nd()?;
    w.extend(data.iter().copied())?;
    w.finish()?;
    Ok(buf)
}

/// Writes f64 values in C order with the given shape, atomically.
pub fn write_f64(path: &Path, shape: &[usize], data: &[f64]) -> Result<(), FileError> {
    debug_assert_eq!(shape.iter().product::<usize>(), data.len());
    let bytes = encode(shape, data).map_err(|e| FileError::write(path, e))?;
    super::write_atomic(path, &bytes)
}

/// Writes values as f32 in C order with the given shape, atomically.
pub fn write_f32(path: &Path, shape: &[usize], data: &[f64]) -> Result<(), FileError> {
    let narrow: Vec<f32> = data.iter().map(|&v| v as f32).collect();
    let bytes = encode(shape, &narrow).map_err(|e| FileError::write(path, e))?;
    super::write_atomic(path, &bytes)
}

/// Reads a numeric `.npy` (float or integer, any byte order) into f64 in C order.
pub fn read(path: &Path) -> Result<Array, FileError> {
    let bytes = std::fs::read(path).map_err(|e| FileError::read(path, e))?;
    decode(&bytes).map_err(|e| FileError::format(path, e.to_string()))
}

/// Why bytes are not a `.npy` polnlos can read: each variant names what in
/// the header or the data was wrong.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NpyError {
    /// The bytes are not a `.npy` at all (npyz's reason).
    #[error("not a .npy file ({0})")]
    NotNpy(String),
    /// A dimension of the header's shape does not fit this machine.
    #[error("shape {0:?} has a dimension too large for this machine")]
    DimensionTooLarge(Vec<u64>),
    /// The header's shape multiplies past the machine's integers.
    #[error("shape {0:?}: the number of values overflows")]
    Overflow(Vec<u64>),
    /// The header announces more values than the file holds.
    #[error("shape {shape:?} announces {count} values of {item_size} bytes, but the file has only {file_len} bytes; it is truncated or its header is wrong")]
    Truncated {
        /// The header's shape.
        shape: Vec<u64>,
        /// The values it announces.
        count: usize,
        /// Bytes per value.
        item_size: usize,
        /// Bytes of data in the file.
        file_len: usize,
    },
    /// The data could not be read as the header's dtype (npyz's reason).
    #[error("{0}")]
    Data(String),
    /// A dtype polnlos does not read.
    #[error("dtype {0:?} is not supported; save as float64 or float32")]
    Dtype(String),
    /// The data hold another number of values than the shape says.
    #[error("the header's shape {shape:?} does not match the {values} values in the file")]
    Count {
        /// The header's shape.
        shape: Vec<usize>,
        /// The values read.
        values: usize,
    },
}

/// Values of `shape` in Fortran order (first index fastest) in C order
/// (last index fastest). Why: MATLAB and `np.asfortranarray` write images so.
fn c_order(shape: &[usize], fortran: &[f64]) -> Vec<f64> {
    let mut out = Vec::with_capacity(fortran.len());
    let mut index = vec![0usize; shape.len()];
    for _ in 0..fortran.len() {
        // The Fortran offset of the C-order position `index`.
        let (mut at, mut stride) = (0, 1);
        for (i, d) in index.iter().zip(shape) {
            at += i * stride;
            stride *= d;
        }
        out.push(fortran[at]);
        for (i, d) in index.iter_mut().zip(shape).rev() {
            *i += 1;
            if *i < *d {
                break;
            }
            *i = 0;
        }
    }
    out
}

/// Decodes `.npy` bytes (see [`read`]); a parser any input may reach, so it never panics.
pub fn decode(bytes: &[u8]) -> Result<Array, NpyError> {
    // npyz multiplies the shape unchecked: check the header's shape first.
    let data_len = match header_shape(bytes) {
        Some((shape, offset)) => {
            let data_len = bytes.len().saturating_sub(offset);
            checked_shape(&shape, 1, data_len)?;
            data_len
        }
        None => bytes.len(),
    };
    let npy = npyz::NpyFile::new(bytes).map_err(|e| NpyError::NotNpy(e.to_string()))?;
    let fortran = npy.order() == npyz::Order::Fortran;
    let kind = npy.dtype().descr();
    let code = kind
        .trim_matches(['\'', '"'])
        .trim_start_matches(['<', '>', '|', '='])
        .to_string();
    let shape = checked_shape(npy.shape(), item_size(&code), data_len)?;
    let data: Vec<f64> = match code.as_str() {
        "f8" => npy
            .into_vec::<f64>()
            .map_err(|e| NpyError::Data(e.to_string()))?,
        "f4" => npy
            .into_vec::<f32>()
            .map_err(|e| NpyError::Data(e.to_string()))?
            .into_iter()
            .map(f64::from)
            .collect(),
        "u2" => npy
            .into_vec::<u16>()
            .map_err(|e| NpyError::Data(e.to_string()))?
            .into_iter()
            .map(f64::from)
            .collect(),
        "u1" => npy
            .into_vec::<u8>()
            .map_err(|e| NpyError::Data(e.to_string()))?
            .into_iter()
            .map(f64::from)
            .collect(),
        "i4" => npy
            .into_vec::<i32>()
            .map_err(|e| NpyError::Data(e.to_string()))?
            .into_iter()
            .map(f64::from)
            .collect(),
        "i8" => npy
            .into_vec::<i64>()
            .map_err(|e| NpyError::Data(e.to_string()))?
            .into_iter()
            .map(|v| v as f64)
            .collect(),
        other => return Err(NpyError::Dtype(other.to_string())),
    };
    if data.len() != shape.iter().product::<usize>() {
        return Err(NpyError::Count {
            shape,
            values: data.len(),
        });
    }
    let data = match fortran {
        true => c_order(&shape, &data),
        false => data,
    };
    let unsigned_bits = match code.as_str() {
        "u1" => Some(8),
        "u2" => Some(16),
        _ => None,
    };
    Ok(Array {
        shape,
        data,
        unsigned_bits,
    })
}

/// The `shape` tuple of a `.npy` header as written, and where the data
/// start (None when the header cannot be found; the full parser then reports
/// what is wrong).
fn header_shape(bytes: &[u8]) -> Option<(Vec<u64>, usize)> {
    let rest = bytes.strip_prefix(b"\x93NUMPY")?;
    let (&major, rest) = rest.split_first()?;
    let rest = rest.get(1..)?;
    let (len, rest, prefix) = if major == 1 {
        (
            usize::from(u16::from_le_bytes([*rest.first()?, *rest.get(1)?])),
            rest.get(2..)?,
            10,
        )
    } else {
        let b = rest.get(..4)?;
        (
            usize::try_from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])).ok()?,
            rest.get(4..)?,
            12,
        )
    };
    let text = std::str::from_utf8(rest.get(..len.min(rest.len()))?).ok()?;
    let after = &text[text.find("shape")?..];
    let open = after.find('(')?;
    let close = after[open..].find(')')? + open;
    let shape = after[open + 1..close]
        .split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .map(|t| t.trim_end_matches('L').parse::<u64>().ok())
        .collect::<Option<Vec<_>>>()?;
    Some((shape, prefix + len))
}

/// Bytes per value of a dtype code (`f8`, `u2`, ...); 0 when unknown.
fn item_size(code: &str) -> usize {
    code.get(1..).and_then(|n| n.parse().ok()).unwrap_or(0)
}

/// The shape of a header, checked: every dimension fits `usize`, their
/// product does not overflow, and the values it announces fit in the
/// `file_len` bytes actually there (so no allocation is sized by a lie).
fn checked_shape(shape: &[u64], item_size: usize, file_len: usize) -> Result<Vec<usize>, NpyError> {
    let dims: Vec<usize> = shape
        .iter()
        .map(|&d| usize::try_from(d))
        .collect::<Result<_, _>>()
        .map_err(|_| NpyError::DimensionTooLarge(shape.to_vec()))?;
    let count = dims
        .iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d))
        .ok_or_else(|| NpyError::Overflow(shape.to_vec()))?;
    let needed = count.checked_mul(item_size.max(1));
    if needed.is_none_or(|n| n > file_len) {
        return Err(NpyError::Truncated {
            shape: shape.to_vec(),
            count,
            item_size,
            file_len,
        });
    }
    Ok(dims)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_f64_and_f32() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.npy");
        let data = vec![1.0, -2.5, 3.25, 1e-300, 7.0, 8.0];
        write_f64(&p, &[2, 3], &data).unwrap();
        let a = read(&p).unwrap();
        assert_eq!(a.shape, vec![2, 3]);
        assert_eq!(a.data, data);
        write_f32(&p, &[6], &data).unwrap();
        let b = read(&p).unwrap();
        assert_eq!(b.data[2], 3.25);
        assert_eq!(b.data[3], 0.0);
    }

    #[test]
    fn a_fortran_ordered_image_reads_in_c_order() {
        // np.asfortranarray(np.arange(24).reshape(2, 3, 4)) writes
        // element (i, j, k) at i + 2 j + 6 k.
        let shape = [2, 3, 4];
        let mut fortran = vec![0.0; 24];
        for c in 0..24 {
            let (i, j, k) = (c / 12, c / 4 % 3, c % 4);
            fortran[i + 2 * j + 6 * k] = c as f64;
        }
        let want: Vec<f64> = (0..24).map(f64::from).collect();
        assert_eq!(c_order(&shape, &fortran), want);
        // Two dimensions: the transpose.
        assert_eq!(c_order(&[2, 3], &[0.0, 3.0, 1.0, 4.0, 2.0, 5.0]), want[..6]);
    }

    /// A valid `.npy` header (version 1.0) for `descr` and `shape`, then `body`.
    fn with_header(descr: &str, shape: &str, body: &[u8]) -> Vec<u8> {
        let mut h = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
        while (10 + h.len() + 1) % 64 != 0 {
            h.push(' ');
        }
        h.push('\n');
        let mut out = b"\x93NUMPY\x01\x00".to_vec();
        out.extend_from_slice(&(h.len() as u16).to_le_bytes());
        out.extend_from_slice(h.as_bytes());
        out.extend_from_slice(body);
        out
    }

    #[test]
    fn lying_shapes_are_errors_not_panics() {
        let ok = decode(&with_header("<f8", "(2,)", &[0u8; 16])).unwrap();
        assert_eq!(ok.shape, vec![2]);
        for shape in [
            "(4294967296, 4294967296)",
            "(18446744073709551615,)",
            "(3,)",
            "(1000000, 1000000, 1000000)",
        ] {
            let e = decode(&with_header("<f8", shape, &[0u8; 16])).unwrap_err();
            assert!(e.to_string().contains("shape"), "{shape}: {e}");
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 256, rng_seed: proptest::test_runner::RngSeed::Fixed(8), ..Default::default() })]
        /// Any header and body: a value or a named error, never a panic.
        #[test]
        fn any_header_decodes_or_errs(
            descr in proptest::sample::select(vec!["<f8", ">f4", "<u2", "|u1", "<i4", "<i8", "<c16", "x"]),
            dims in proptest::collection::vec(0u64..u64::MAX, 0..4),
            small in proptest::collection::vec(0u64..5, 0..4),
            use_small: bool,
            body in proptest::collection::vec(proptest::num::u8::ANY, 0..200),
        ) {
            let d = if use_small { small } else { dims };
            let shape = format!("({})", d.iter().map(|v| format!("{v},")).collect::<String>());
            if let Ok(a) = decode(&with_header(descr, &shape, &body)) {
                proptest::prop_assert_eq!(a.data.len(), a.shape.iter().product::<usize>());
            }
        }

        /// Arbitrary bytes after the magic: never a panic.
        #[test]
        fn any_bytes_decode_or_err(body in proptest::collection::vec(proptest::num::u8::ANY, 0..300)) {
            let mut b = b"\x93NUMPY\x01\x00".to_vec();
            b.extend_from_slice(&body);
            let _ = decode(&b);
        }
    }

    #[test]
    fn garbage_is_a_format_error() {
        assert!(decode(b"not numpy at all").is_err());
    }
}
