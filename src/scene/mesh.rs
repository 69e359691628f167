//! Triangle meshes read from Wavefront OBJ and STL files (the `mesh` occluder).
//!
//! The parsers take the file's bytes and return its triangles or an error
//! that says what is wrong; nothing in a file can make them panic or
//! allocate beyond [`MAX_TRIANGLES`].

use std::io::Read;
use std::path::Path;

use crate::optics::Vec3;

/// Most triangles a mesh may have: a 1e6-triangle chair is already far finer
/// than any wall a camera resolves, and every triangle is tested per ray.
pub const MAX_TRIANGLES: usize = 1_000_000;
/// Most vertices an OBJ file may list (three per triangle).
pub(crate) const MAX_VERTICES: usize = 3 * MAX_TRIANGLES;
/// Largest mesh file read, bytes (a binary STL of [`MAX_TRIANGLES`] is 50 MB).
pub const MAX_BYTES: u64 = 256 << 20;
/// Largest coordinate accepted after `scale` and `offset`, metres: a mesh
/// kilometres away is a unit mistake (millimetres read as metres).
pub const MAX_COORD: f64 = 1e4;

/// What is wrong with a mesh file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshError {
    /// The file cannot be read.
    #[error("cannot read {path}: {message}")]
    Read {
        /// The path as resolved.
        path: String,
        /// Why.
        message: String,
    },
    /// The file is not an `.obj` or `.stl` by its name.
    #[error("{path}: the file name must end in .obj (Wavefront OBJ) or .stl")]
    Format {
        /// The path as resolved.
        path: String,
    },
    /// A line of an OBJ or ASCII STL file is malformed.
    #[error("line {line}: {message}")]
    Line {
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A binary STL whose size does not match its triangle count.
    #[error("binary STL header says {count} triangles, which is {expected} bytes, but the file has {actual} bytes (and it is not ASCII STL)")]
    StlSize {
        /// Triangle count in the header.
        count: u32,
        /// `84 + 50 count`.
        expected: u64,
        /// File size.
        actual: u64,
    },
    /// Too many triangles or vertices.
    #[error("has more than {limit} {what}")]
    TooMany {
        /// `"triangles"` or `"vertices"`.
        what: &'static str,
        /// The limit.
        limit: usize,
    },
    /// A vertex that is not finite or absurdly far after scale and offset.
    #[error("vertex {vertex:?} (after scale and offset) is not three finite numbers within {MAX_COORD} m")]
    Coordinate {
        /// The offending vertex.
        vertex: [f64; 3],
    },
    /// Nothing to block with.
    #[error("has no triangles of non-zero area ({faces} faces read)")]
    Empty {
        /// Faces (or facets) the file had.
        faces: usize,
    },
}

fn line_error(line: usize, message: impl Into<String>) -> MeshError {
    MeshError::Line {
        line,
        message: message.into(),
    }
}

/// Triangles as the file gives them, before scale and offset.
pub(crate) type RawTriangles = Vec<[[f64; 3]; 3]>;

/// Reads a mesh file: OBJ or STL by its extension, at most [`MAX_BYTES`].
pub fn read(path: &Path) -> Result<RawTriangles, MeshError> {
    let shown = path.display().to_string();
    let read_error = |message: String| MeshError::Read {
        path: shown.clone(),
        message,
    };
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    let parse: fn(&[u8]) -> Result<RawTriangles, MeshError> = match ext.as_deref() {
        Some("obj") => parse_obj,
        Some("stl") => parse_stl,
        _ => return Err(MeshError::Format { path: shown }),
    };
    let file = std::fs::File::open(path).map_err(|e| read_error(e.to_string()))?;
    let meta = file.metadata().map_err(|e| read_error(e.to_string()))?;
    // A device or a fifo could stream for ever.
    if !meta.is_file() {
        return Err(read_error("not a regular file".into()));
    }
    if meta.len() > MAX_BYTES {
        return Err(read_error(format!(
            "{} bytes, more than the {MAX_BYTES} a mesh may have",
            meta.len()
        )));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(MAX_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| read_error(e.to_string()))?;
    if bytes.len() as u64 > MAX_BYTES {
        return Err(read_error(format!(
            "more than the {MAX_BYTES} bytes a mesh may have"
        )));
    }
    parse(&bytes)
}

/// A vertex of three numbers from whitespace-separated tokens.
fn three(
    line: usize,
    what: &str,
    tokens: &mut dyn Iterator<Item = &str>,
) -> Result<[f64; 3], MeshError> {
    let mut v = [0.0; 3];
    for x in &mut v {
        let t = tokens
            .next()
            .ok_or_else(|| line_error(line, format!("{what} needs three numbers")))?;
        *x = t
            .parse()
            .map_err(|_| line_error(line, format!("{what}: {t:?} is not a number")))?;
    }
    Ok(v)
}

/// Wavefront OBJ: `v x y z` vertices and `f` faces of 3 or more vertex
/// references (`i`, `i/t`, `i//n`, `i/t/n`; negative counts back from the
/// last vertex read), polygons fan-triangulated; other statements ignored.
pub(crate) fn parse_obj(bytes: &[u8]) -> Result<RawTriangles, MeshError> {
    let text = String::from_utf8_lossy(bytes);
    let mut vertices: Vec<[f64; 3]> = Vec::new();
    // Vertex indices (0-based) of each triangle and the line that made it.
    let mut faces: Vec<([usize; 3], usize)> = Vec::new();
    let mut polygons = 0usize;
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let content = raw.split('#').next().unwrap_or("");
        let mut tokens = content.split_whitespace();
        match tokens.next() {
            Some("v") => {
                if vertices.len() >= MAX_VERTICES {
                    return Err(MeshError::TooMany {
                        what: "vertices",
                        limit: MAX_VERTICES,
                    });
                }
                vertices.push(three(line, "v", &mut tokens)?);
            }
            Some("f") => {
                polygons += 1;
                let mut refs = Vec::new();
                for t in tokens {
                    let index = t.split('/').next().unwrap_or("");
                    let k: i64 = index
                        .parse()
                        .map_err(|_| line_error(line, format!("f: {t:?} is not a vertex index")))?;
                    let resolved = match k {
                        0 => None,
                        k if k > 0 => usize::try_from(k - 1).ok(),
                        // -1 is the last vertex read so far.
                        k => (vertices.len() as i64)
                            .checked_add(k)
                            .filter(|r| *r >= 0)
                            .map(|r| r as usize),
                    };
                    let resolved = resolved.ok_or_else(|| {
                        line_error(
                            line,
                            format!(
                                "f: vertex index {k} is out of range ({} vertices so far; indices count from 1, negative ones back from the last)",
                                vertices.len()
                            ),
                        )
                    })?;
                    refs.push(resolved);
                    if refs.len() > MAX_VERTICES {
                        break;
                    }
                }
                if refs.len() < 3 {
                    return Err(line_error(
                        line,
                        format!("f needs at least 3 vertices, has {}", refs.len()),
                    ));
                }
                if faces.len() + refs.len() - 2 > MAX_TRIANGLES {
                    return Err(MeshError::TooMany {
                        what: "triangles",
                        limit: MAX_TRIANGLES,
                    });
                }
                for k in 1..refs.len() - 1 {
                    faces.push(([refs[0], refs[k], refs[k + 1]], line));
                }
            }
            _ => {}
        }
    }
    let mut out = Vec::with_capacity(faces.len());
    for (f, line) in faces {
        let mut tri = [[0.0; 3]; 3];
        for (corner, &k) in tri.iter_mut().zip(&f) {
            *corner = *vertices.get(k).ok_or_else(|| {
                line_error(
                    line,
                    format!(
                        "f: vertex index {} is out of range (the file has {} vertices)",
                        k + 1,
                        vertices.len()
                    ),
                )
            })?;
        }
        out.push(tri);
    }
    if out.is_empty() {
        return Err(MeshError::Empty { faces: polygons });
    }
    Ok(out)
}

/// STL, binary when its size is `84 + 50 n` for the header's `n` (and it
/// does not read as ASCII STL), ASCII when it starts with `solid`.
pub(crate) fn parse_stl(bytes: &[u8]) -> Result<RawTriangles, MeshError> {
    let solid = bytes.trim_ascii_start().starts_with(b"solid");
    // Binary headers often start with "solid" too; ASCII STL is all text.
    let text = solid && bytes.is_ascii();
    if text && bytes.windows(5).any(|w| w == b"facet") {
        return parse_stl_ascii(bytes);
    }
    if let Some(header) = bytes.get(80..84) {
        let count = u32::from_le_bytes([header[0], header[1], header[2], header[3]]);
        let expected = 84 + 50 * u64::from(count);
        if expected == bytes.len() as u64 {
            return parse_stl_binary(&bytes[84..], count);
        }
        if !text {
            return Err(MeshError::StlSize {
                count,
                expected,
                actual: bytes.len() as u64,
            });
        }
    }
    if solid {
        return parse_stl_ascii(bytes);
    }
    Err(line_error(
        1,
        format!(
            "{} bytes is neither a binary STL (84-byte header, then 50 bytes per triangle) nor ASCII STL (starting with \"solid\")",
            bytes.len()
        ),
    ))
}

fn parse_stl_binary(body: &[u8], count: u32) -> Result<RawTriangles, MeshError> {
    if count as usize > MAX_TRIANGLES {
        return Err(MeshError::TooMany {
            what: "triangles",
            limit: MAX_TRIANGLES,
        });
    }
    let f = |b: &[u8]| f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    let out: RawTriangles = body
        .chunks_exact(50)
        .map(|c| {
            // Bytes 0..12 are the facet normal, 48..50 the attribute count.
            let v = |k: usize| {
                let o = 12 + 12 * k;
                [f(&c[o..]), f(&c[o + 4..]), f(&c[o + 8..])]
            };
            [v(0), v(1), v(2)]
        })
        .collect();
    if out.is_empty() {
        return Err(MeshError::Empty { faces: 0 });
    }
    Ok(out)
}

fn parse_stl_ascii(bytes: &[u8]) -> Result<RawTriangles, MeshError> {
    let text = String::from_utf8_lossy(bytes);
    let mut out = Vec::new();
    let mut pending: Vec<[f64; 3]> = Vec::new();
    let mut facets = 0usize;
    let mut last = 0;
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        last = line;
        let mut tokens = raw.split_whitespace();
        match tokens.next() {
            Some("vertex") => {
                if pending.len() >= 3 {
                    return Err(line_error(line, "a facet's loop has more than 3 vertices"));
                }
                pending.push(three(line, "vertex", &mut tokens)?);
            }
            Some("endloop") => {
                facets += 1;
                let [a, b, c] = pending[..] else {
                    return Err(line_error(
                        line,
                        format!("a facet needs 3 vertices, has {}", pending.len()),
                    ));
                };
                if out.len() >= MAX_TRIANGLES {
                    return Err(MeshError::TooMany {
                        what: "triangles",
                        limit: MAX_TRIANGLES,
                    });
                }
                out.push([a, b, c]);
                pending.clear();
            }
            _ => {}
        }
    }
    if !pending.is_empty() {
        return Err(line_error(last, "the last facet has no endloop"));
    }
    if out.is_empty() {
        return Err(MeshError::Empty { faces: facets });
    }
    Ok(out)
}

/// Triangles in metres: `scale x + offset` of each raw vertex, checked
/// finite and within [`MAX_COORD`]; triangles of zero area are dropped
/// (they block nothing), and none left is an error.
pub fn place(raw: &[[[f64; 3]; 3]], scale: f64, offset: Vec3) -> Result<Vec<[Vec3; 3]>, MeshError> {
    let mut out = Vec::with_capacity(raw.len());
    for tri in raw {
        let mut t = [Vec3::zeros(); 3];
        for (p, v) in t.iter_mut().zip(tri) {
            *p = Vec3::from(*v) * scale + offset;
            if !p.iter().all(|x| x.is_finite() && x.abs() <= MAX_COORD) {
                return Err(MeshError::Coordinate {
                    vertex: [p.x, p.y, p.z],
                });
            }
        }
        // Degenerate as a rect's half-extents are (a zero or parallel edge).
        let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
        if e1.cross(&e2).norm() > 1e-12 * e1.norm() * e2.norm() {
            out.push(t);
        }
    }
    if out.is_empty() {
        return Err(MeshError::Empty { faces: raw.len() });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn obj_reads_polygons_slashes_and_negative_indices() {
        let obj = b"# a unit square and a triangle\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0 1.0\nvt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3//1 4\nf -4 -3 -2\ng x\n";
        let t = parse_obj(obj).unwrap();
        assert_eq!(t.len(), 3);
        assert_eq!(t[0], [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]]);
        assert_eq!(t[1], [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]]);
        assert_eq!(t[2], [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]]);
        // Double precision survives.
        let t = parse_obj(b"v 0.1234567890123456 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
        assert_eq!(t[0][0][0], 0.1234567890123456);
    }

    #[test]
    fn obj_errors_name_the_line() {
        let cases: [(&[u8], &str); 6] = [
            (b"v 0 0 0\nv 1 0 0\nf 1 2 3\n", "line 3"),
            (b"v 0 0\n", "line 1: v needs three numbers"),
            (b"v 0 0 x\n", "line 1"),
            (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "at least 3"),
            (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "out of range"),
            (b"v 0 0 0\n", "no triangles"),
        ];
        for (text, want) in cases {
            let e = parse_obj(text).unwrap_err().to_string();
            assert!(e.contains(want), "{e}");
        }
        let e = parse_obj(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 1 2\n").unwrap_err();
        assert!(e.to_string().contains("line 4"), "{e}");
    }

    fn binary(tris: &[[[f32; 3]; 3]], count: u32) -> Vec<u8> {
        let mut b = b"solid but binary".to_vec();
        b.resize(80, 0);
        b.extend(count.to_le_bytes());
        for t in tris {
            b.extend([0u8; 12]);
            for v in t {
                for x in v {
                    b.extend(x.to_le_bytes());
                }
            }
            b.extend([0u8; 2]);
        }
        b
    }

    #[test]
    fn stl_binary_and_ascii() {
        let tri = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.5, 0.0]];
        let t = parse_stl(&binary(&[tri], 1)).unwrap();
        assert_eq!(t, vec![[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.5, 0.0]]]);
        let e = parse_stl(&binary(&[tri], 2)).unwrap_err();
        assert!(matches!(e, MeshError::StlSize { count: 2, .. }), "{e}");
        let mut no_solid = binary(&[tri], 2);
        no_solid[0] = b'x';
        assert!(matches!(
            parse_stl(&no_solid).unwrap_err(),
            MeshError::StlSize { .. }
        ));
        let ascii = b"solid x\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n   vertex 0 0.5 0\n  endloop\n endfacet\nendsolid x\n";
        assert_eq!(parse_stl(ascii).unwrap(), t);
        let short = b"solid x\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n  endloop\n endfacet\nendsolid x\n";
        assert!(parse_stl(short).unwrap_err().to_string().contains("line 6"));
        assert!(parse_stl(b"solid x\nendsolid x\n").is_err());
        assert!(parse_stl(b"").is_err());
    }

    #[test]
    fn place_scales_offsets_checks_and_drops_slivers() {
        let raw = [
            [[0.0, 0.0, 0.0], [1000.0, 0.0, 0.0], [0.0, 1000.0, 0.0]],
            [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]],
        ];
        let t = place(&raw, 1e-3, Vec3::new(0.0, 0.0, 1.0)).unwrap();
        assert_eq!(t.len(), 1);
        assert_eq!(t[0][1], Vec3::new(1.0, 0.0, 1.0));
        assert!(matches!(
            place(&raw, 1e3, Vec3::zeros()),
            Err(MeshError::Coordinate { .. })
        ));
        assert!(matches!(
            place(&raw[1..], 1.0, Vec3::zeros()),
            Err(MeshError::Empty { faces: 1 })
        ));
        let nan = [[[f64::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]];
        assert!(place(&nan, 1.0, Vec3::zeros()).is_err());
    }

    proptest::proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..600)) {
            let _ = parse_obj(&bytes);
            let _ = parse_stl(&bytes);
        }

        #[test]
        fn arbitrary_obj_lines_never_panic(lines in proptest::collection::vec(
            proptest::sample::select(vec!["v 0 0 0", "v 1 0 0", "v 1e308 1e308 0", "v nan 0 0", "f 1 2 3", "f -1 -2 -3", "f 1/2/3 2//4 3/", "f 9999999999999999999 1 2", "f -9223372036854775808 1 2", "f 1 2", "f", "vt 0 0", "# c", "v", "solid"]),
            0..30,
        )) {
            let text = lines.join("\n");
            if let Ok(t) = parse_obj(text.as_bytes()) {
                let _ = place(&t, 1.0, Vec3::zeros());
            }
            let _ = parse_stl(text.as_bytes());
        }

        #[test]
        fn arbitrary_binary_stl_bodies_never_panic(
            body in proptest::collection::vec(proptest::num::u8::ANY, 0..300),
            count in 0u32..8,
        ) {
            let mut b = vec![0u8; 80];
            b.extend(count.to_le_bytes());
            b.extend(body);
            if let Ok(t) = parse_stl(&b) {
                let _ = place(&t, 1.0, Vec3::zeros());
            }
        }
    }
}
