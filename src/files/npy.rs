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
    decode(&bytes).map_err(|reason| FileError::format(path, reason))
}

fn decode(bytes: &[u8]) -> Result<Array, String> {
    let npy = npyz::NpyFile::new(bytes).map_err(|e| format!("not a .npy file ({e})"))?;
    let shape: Vec<usize> = npy.shape().iter().map(|&s| s as usize).collect();
    let fortran = npy.order() == npyz::Order::Fortran;
    let kind = npy.dtype().descr();
    let code = kind
        .trim_matches(['\'', '"'])
        .trim_start_matches(['<', '>', '|', '=']);
    let data: Vec<f64> = match code {
        "f8" => npy.into_vec::<f64>().map_err(|e| e.to_string())?,
        "f4" => npy
            .into_vec::<f32>()
            .map_err(|e| e.to_string())?
            .into_iter()
            .map(f64::from)
            .collect(),
        "u2" => npy
            .into_vec::<u16>()
            .map_err(|e| e.to_string())?
            .into_iter()
            .map(f64::from)
            .collect(),
        "u1" => npy
            .into_vec::<u8>()
            .map_err(|e| e.to_string())?
            .into_iter()
            .map(f64::from)
            .collect(),
        "i4" => npy
            .into_vec::<i32>()
            .map_err(|e| e.to_string())?
            .into_iter()
            .map(f64::from)
            .collect(),
        "i8" => npy
            .into_vec::<i64>()
            .map_err(|e| e.to_string())?
            .into_iter()
            .map(|v| v as f64)
            .collect(),
        other => {
            return Err(format!(
                "dtype {other:?} is not supported; save as float64 or float32"
            ))
        }
    };
    let data = if fortran && shape.len() == 2 {
        let (r, c) = (shape[0], shape[1]);
        let mut out = vec![0.0; data.len()];
        for j in 0..c {
            for i in 0..r {
                out[i * c + j] = data[j * r + i];
            }
        }
        out
    } else if fortran && shape.len() > 2 {
        return Err("Fortran-ordered arrays of more than 2 dimensions are not supported; save with numpy.ascontiguousarray".into());
    } else {
        data
    };
    Ok(Array { shape, data })
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
    fn garbage_is_a_format_error() {
        assert!(decode(b"not numpy at all").is_err());
    }
}
