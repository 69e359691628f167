//! Which camera pixels image which wall element, and with what footprint
//! (MODEL.md "From camera frames to i"): the one assignment the measurement
//! averages over and the `"pixels"` rows of `T` integrate over.
//!
//! Why one type: `i_j` and row `j` of `T` must average over exactly the same
//! pixels with the same weights, or the difference goes into the image.

use rayon::prelude::*;

use super::{Homography, Plane};

/// Most lattice points one map may look at (the wall's image bounding box):
/// a 16k x 16k sensor. A homography that images the wall larger than that is
/// refused before anything is allocated.
pub(crate) const MAX_LATTICE_POINTS: u64 = 1 << 28;

/// A set of the four positions of a sensor's 2x2 pattern, `(column mod 2,
/// row mod 2)` in sensor coordinates: the pixels behind one micro-polarizer
/// of a mosaic, or behind one colour of a Bayer filter (green has two).
///
/// Why a set: a Bayer filter's green is two of the four positions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Cells(u8);

impl Cells {
    /// Every pixel.
    pub const ALL: Cells = Cells(0b1111);

    /// The pixels at column and row `cell` mod 2.
    pub fn one(cell: [u32; 2]) -> Self {
        Cells(1 << ((cell[1] % 2) * 2 + cell[0] % 2))
    }

    /// The pixels at any of `cells`.
    pub fn any(cells: &[[u32; 2]]) -> Self {
        Cells(cells.iter().fold(0, |m, &c| m | Self::one(c).0))
    }

    /// Whether sensor row `y` holds a pixel of the set.
    pub fn in_row(self, y: i64) -> bool {
        self.0 & (0b11 << (y.rem_euclid(2) * 2)) != 0
    }

    /// Whether sensor pixel `(x, y)` is in the set.
    pub fn contains(self, x: i64, y: i64) -> bool {
        self.0 & (1 << (y.rem_euclid(2) * 2 + x.rem_euclid(2))) != 0
    }
}

impl From<Option<[u32; 2]>> for Cells {
    /// A mosaic block's one cell, or every pixel.
    fn from(cell: Option<[u32; 2]>) -> Self {
        cell.map_or(Cells::ALL, Cells::one)
    }
}

/// Where a frame's pixels lie on the sensor: its region's offset and size
/// and its binning (MODEL.md: binned pixel `(X, Y)` of a region starting at
/// `(x0, y0)` has its centre at `(x0 + b X + (b - 1)/2, y0 + b Y + (b - 1)/2)`
/// in the unbinned coordinates `H` maps to).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct FrameGeometry {
    /// Region offset `[x0, y0]`, unbinned sensor pixels.
    pub offset: [u32; 2],
    /// Frame size `[width, height]`, (binned) pixels.
    pub size: [usize; 2],
    /// Binning `[bx, by]`.
    pub binning: [u32; 2],
}

impl FrameGeometry {
    /// A whole frame of `width` x `height` pixels at the sensor's origin, unbinned.
    pub fn plain(width: usize, height: usize) -> Self {
        Self {
            offset: [0, 0],
            size: [width, height],
            binning: [1, 1],
        }
    }

    /// Centre of frame pixel (X, Y) in the unbinned sensor coordinates `H` maps to.
    pub fn centre(&self, x: usize, y: usize) -> (f64, f64) {
        (self.sensor(0, x as i64), self.sensor(1, y as i64))
    }

    /// Whether every pixel centre in the bounding box of the wall's image
    /// through `h` lies in this frame: then no wall element is imaged even
    /// partly outside it, which [`PixelMap::frame`] would otherwise find by
    /// mapping every pixel.
    ///
    /// Why: a request's check must not cost a whole pixel map (tens of MB
    /// for a large frame) for every request a client sends.
    pub fn holds_wall(
        &self,
        h: &Homography,
        wall: &Plane,
        pose: &str,
    ) -> Result<bool, FootprintError> {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for [x, y] in wall_corners(h, wall, pose)? {
            lo = [lo[0].min(x), lo[1].min(y)];
            hi = [hi[0].max(x), hi[1].max(y)];
        }
        let inside = |a: usize| {
            let (k0, k1) = self.indices(a, lo[a], hi[a]);
            k0 >= 0 && k1 < self.size[a] as i64
        };
        Ok(inside(0) && inside(1))
    }

    /// Sensor coordinate of pixel index `k` along axis `a` (0: x, 1: y).
    fn sensor(&self, a: usize, k: i64) -> f64 {
        let b = f64::from(self.binning[a]);
        f64::from(self.offset[a]) + b * k as f64 + (b - 1.0) / 2.0
    }

    /// The pixel indices along axis `a` whose centres lie in `[lo, hi]`
    /// (unbinned coordinates), unclipped to the frame.
    fn indices(&self, a: usize, lo: f64, hi: f64) -> (i64, i64) {
        let b = f64::from(self.binning[a]);
        let base = f64::from(self.offset[a]) + (b - 1.0) / 2.0;
        (
            ((lo - base) / b).ceil() as i64,
            ((hi - base) / b).floor() as i64,
        )
    }
}

/// The wall's four corners `(-u, -v), (+u, -v), (+u, +v), (-u, +v)` in the
/// unbinned sensor coordinates `h` maps to: where a pose's camera sees the
/// wall, to bound a pixel scan or aim a live view at it.
pub fn wall_corners(
    h: &Homography,
    wall: &Plane,
    pose: &str,
) -> Result<[[f64; 2]; 4], FootprintError> {
    let [hu, hv] = [wall.size[0] / 2.0, wall.size[1] / 2.0];
    let mut out = [[0.0; 2]; 4];
    for (k, (u, v)) in [(-hu, -hv), (hu, -hv), (hu, hv), (-hu, hv)]
        .into_iter()
        .enumerate()
    {
        let (x, y) = h
            .apply(u, v)
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .ok_or_else(|| FootprintError::NotInView {
                pose: pose.to_string(),
                u,
                v,
            })?;
        out[k] = [x, y];
    }
    Ok(out)
}

/// Why no pixel map could be made for a pose.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FootprintError {
    /// A wall corner maps behind the camera or to infinity.
    #[error("pose {pose:?}: wall corner (u = {u:+.3} m, v = {v:+.3} m) maps behind the camera or to infinity through the homography; the pose cannot see the whole wall: check its homography")]
    NotInView {
        /// Pose name.
        pose: String,
        /// The corner's wall coordinates.
        u: f64,
        /// Likewise.
        v: f64,
    },
    /// The wall's image covers more lattice points than any sensor has.
    #[error("pose {pose:?}: the homography images the wall over {points} pixels, more than the {max} a map is made for; check its scale (wall metres to pixels)")]
    TooLarge {
        /// Pose name.
        pose: String,
        /// Lattice points in the wall's image bounding box.
        points: u64,
        /// The limit.
        max: u64,
    },
    /// Not one pixel of the frame images a wall element.
    #[error("pose {pose:?}: the homography images no wall element into the {width}x{height} frame; check the homography and the region of interest")]
    NoElement {
        /// Pose name.
        pose: String,
        /// Frame width, pixels.
        width: usize,
        /// Frame height, pixels.
        height: usize,
    },
    /// A wall element whose image holds no pixel centre.
    #[error("pose {pose:?}: wall element {element} (iu {iu}, iv {iv}) holds no pixel centre: the camera sees it smaller than a pixel; use a coarser wall grid, less binning or a closer camera")]
    NoPixel {
        /// Pose name.
        pose: String,
        /// Flat element index.
        element: usize,
        /// Element column.
        iu: usize,
        /// Element row.
        iv: usize,
    },
    /// A wall element imaged partly outside the frame.
    #[error("pose {pose:?}: wall element {element} (iu {iu}, iv {iv}) is imaged partly outside the frame (region at {offset:?}, {width}x{height} pixels, binning {binning:?}); capture a region that holds the whole wall")]
    OutsideFrame {
        /// Pose name.
        pose: String,
        /// Flat element index.
        element: usize,
        /// Element column.
        iu: usize,
        /// Element row.
        iv: usize,
        /// The frame's region offset.
        offset: [u32; 2],
        /// Frame width.
        width: usize,
        /// Frame height.
        height: usize,
        /// Binning.
        binning: [u32; 2],
    },
}

/// The pixels of every wall element with their normalized footprint weights
/// `a_p / sum a_p`, element-major (compressed rows: element `j`'s pixels at
/// `starts[j]..starts[j + 1]`).
#[derive(Debug, Clone, PartialEq)]
pub struct PixelMap {
    starts: Vec<usize>,
    /// Flat frame index `Y width + X` of each pixel (frame maps only).
    pixels: Vec<usize>,
    weights: Vec<f64>,
    /// Wall coordinates `H^-1(p)` of each pixel (plane maps only).
    points: Vec<[f64; 2]>,
    geometry: Option<FrameGeometry>,
}

/// One lattice point inside the wall.
struct Hit {
    element: u32,
    pixel: usize,
    area: f64,
    point: [f64; 2],
}

impl PixelMap {
    /// The pixels of `geometry`'s frame that image each element of `wall`
    /// through `h` (MODEL.md "From camera frames to i"): every element must
    /// hold a pixel and lie wholly inside the frame.
    pub fn frame(
        h: &Homography,
        wall: &Plane,
        geometry: FrameGeometry,
        pose: &str,
    ) -> Result<Self, FootprintError> {
        Self::make(h, wall, Some(geometry), Cells::ALL, pose)
    }

    /// Every integer point of the (unbounded) image plane whose `H^-1` lies in
    /// an element of `wall`, with its wall coordinates: the samples of the
    /// `"pixels"` rows of `T`.
    pub fn plane(h: &Homography, wall: &Plane, pose: &str) -> Result<Self, FootprintError> {
        Self::make(h, wall, None, Cells::ALL, pose)
    }

    /// [`PixelMap::frame`] over the pixels in `cells` only: one
    /// micro-polarizer of a mosaic (MODEL.md "On-chip polarizer mosaic"), one
    /// colour of a Bayer filter, or both (`Cells::ALL`: every pixel).
    pub fn cell_frame(
        h: &Homography,
        wall: &Plane,
        geometry: FrameGeometry,
        cells: Cells,
        pose: &str,
    ) -> Result<Self, FootprintError> {
        Self::make(h, wall, Some(geometry), cells, pose)
    }

    /// [`PixelMap::plane`] over the integer points in `cells` only: the
    /// samples of a mosaic block's `"pixels"` rows.
    pub fn cell_plane(
        h: &Homography,
        wall: &Plane,
        cells: Cells,
        pose: &str,
    ) -> Result<Self, FootprintError> {
        Self::make(h, wall, None, cells, pose)
    }

    /// This frame map with each pixel's value taken from the pixels of
    /// `cells` alone, by bilinear interpolation of its nearest ones (its own
    /// value where it is in `cells`; only pixels of the map, which image the
    /// wall, interpolate): one colour of a Bayer filter averaged over the
    /// whole element. `None` for a plane map or a binned frame.
    ///
    /// Why: the pixels of one colour sit half a pixel off the element's
    /// centroid, so their plain mean is biased where the wall image has a
    /// gradient (by more than the noise on the colour bench of
    /// `tests/core/colour.rs`); interpolated, a linear gradient is exact.
    /// Each element's value is still a weighted sum of its colour's pixels,
    /// so its variance propagates as before.
    pub fn interpolated(&self, cells: Cells) -> Option<Self> {
        let g = self.geometry.filter(|g| g.binning == [1, 1])?;
        let [w, h] = [g.size[0] as i64, g.size[1] as i64];
        let [ox, oy] = [i64::from(g.offset[0]), i64::from(g.offset[1])];
        // Only pixels that image the wall interpolate: past its edge a
        // pixel sees something else.
        let mut on_wall = vec![false; self.geometry.map_or(0, |g| g.size[0] * g.size[1])];
        for &p in &self.pixels {
            on_wall[p] = true;
        }
        let inside = |x: i64, y: i64| (0..w).contains(&x) && (0..h).contains(&y);
        let of = |x: i64, y: i64| {
            cells.contains(ox + x, oy + y) && inside(x, y) && on_wall[(y * w + x) as usize]
        };
        // The pixels of `cells` that interpolate frame pixel (x, y), equally weighted.
        let sources = |x: i64, y: i64| -> Vec<(i64, i64)> {
            if of(x, y) {
                return vec![(x, y)];
            }
            let near: Vec<(i64, i64)> = [(x - 1, y), (x + 1, y), (x, y - 1), (x, y + 1)]
                .into_iter()
                .filter(|&(a, b)| of(a, b))
                .collect();
            if !near.is_empty() {
                return near;
            }
            [
                (x - 1, y - 1),
                (x + 1, y - 1),
                (x - 1, y + 1),
                (x + 1, y + 1),
            ]
            .into_iter()
            .filter(|&(a, b)| of(a, b))
            .collect()
        };
        let mut starts = vec![0];
        let (mut pixels, mut weights) = (Vec::new(), Vec::new());
        for j in 0..self.elements() {
            let mut acc: std::collections::BTreeMap<usize, f64> = Default::default();
            for k in self.range(j) {
                let p = self.pixels[k] as i64;
                let from = sources(p % w, p / w);
                let share = self.weights[k] / from.len().max(1) as f64;
                for (a, b) in from {
                    *acc.entry((b * w + a) as usize).or_default() += share;
                }
            }
            let total: f64 = acc.values().sum();
            for (p, wt) in acc {
                pixels.push(p);
                weights.push(wt / total);
            }
            starts.push(pixels.len());
        }
        Some(Self {
            starts,
            pixels,
            weights,
            points: Vec::new(),
            geometry: self.geometry,
        })
    }

    /// Elements mapped.
    pub fn elements(&self) -> usize {
        self.starts.len() - 1
    }

    /// Pixels mapped (over all elements).
    pub fn len(&self) -> usize {
        self.weights.len()
    }

    /// Whether no pixel is mapped (never, for a map that was made).
    pub fn is_empty(&self) -> bool {
        self.weights.is_empty()
    }

    /// Element `j`'s effective number of pixels, `1 / sum w_p^2` (`(sum a_p)^2 /
    /// sum a_p^2`): its mean carries the noise of that many equal pixels.
    pub fn effective_pixels(&self, j: usize) -> f64 {
        1.0 / self.weights[self.range(j)]
            .iter()
            .map(|w| w * w)
            .sum::<f64>()
    }

    /// The range of element `j`'s pixels in [`PixelMap::weights`] and its kin.
    pub fn range(&self, j: usize) -> std::ops::Range<usize> {
        self.starts[j]..self.starts[j + 1]
    }

    /// Normalized footprint weight of each pixel (those of an element sum to 1).
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// Wall coordinates (u, v) of each pixel; empty for a frame map.
    pub fn points(&self) -> &[[f64; 2]] {
        &self.points
    }

    /// The frame a frame map was made for.
    pub fn geometry(&self) -> Option<FrameGeometry> {
        self.geometry
    }

    /// `(sum_p w_p x_p, sum_p w_p^2 var_p)` of every element over a frame of
    /// `values` and, when given, per-pixel `variance` (MODEL.md `i_j`,
    /// `var_j` with `w_p = a_p / sum a_p`), in one pass over the pixels.
    ///
    /// An element with a NaN pixel (saturated: not measured) is NaN, mean
    /// and variance. Why not a mean over the rest: `T`'s row is the whole
    /// element's mean and the pixels that saturate are its brightest, so a
    /// mean over the others is biased low (with "half of them in range" the
    /// 100 ms rotating captures left 7.6x the noise unexplained).
    ///
    /// # Panics
    /// When `values` (or `variance`) is shorter than the frame this map was
    /// made for; [`PixelMap::frame`] callers check the size first.
    pub fn average(
        &self,
        values: &[f32],
        variance: Option<&(dyn Fn(usize) -> f64 + Sync)>,
    ) -> (Vec<f64>, Option<Vec<f64>>) {
        // One weighted sum per element over its pixels, in parallel.
        let per_element = |term: &(dyn Fn(usize, f64) -> f64 + Sync)| -> Vec<f64> {
            (0..self.elements())
                .into_par_iter()
                .with_min_len(64)
                .map(|j| {
                    let r = self.range(j);
                    self.pixels[r.clone()]
                        .iter()
                        .zip(&self.weights[r])
                        .map(|(&p, &w)| term(p, w))
                        .sum()
                })
                .collect()
        };
        // A NaN pixel makes its element's sum NaN by itself; its variance
        // follows the mean.
        let means = per_element(&|p, w| w * f64::from(values[p]));
        let variances = variance.map(|var| {
            let mut v = per_element(&|p, w| w * w * var(p));
            for (v, m) in v.iter_mut().zip(&means) {
                if m.is_nan() {
                    *v = f64::NAN;
                }
            }
            v
        });
        (means, variances)
    }

    fn make(
        h: &Homography,
        wall: &Plane,
        geometry: Option<FrameGeometry>,
        cells: Cells,
        pose: &str,
    ) -> Result<Self, FootprintError> {
        let g = geometry.unwrap_or(FrameGeometry::plain(0, 0));
        let lattice = Self::lattice(h, wall, &g, pose)?;
        let rows = Self::hits(h, wall, geometry, &g, cells, lattice);
        let counts = Self::counts(&rows, wall, &g, pose)?;
        Ok(Self::assemble(rows, &counts, geometry))
    }

    /// The lattice indices `[(x0, x1), (y0, y1)]` of the wall's image bounding box in `g`.
    /// Bounds the scan, and refuses a homography that images the wall larger than any sensor.
    fn lattice(
        h: &Homography,
        wall: &Plane,
        g: &FrameGeometry,
        pose: &str,
    ) -> Result<[(i64, i64); 2], FootprintError> {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for [x, y] in wall_corners(h, wall, pose)? {
            lo = [lo[0].min(x), lo[1].min(y)];
            hi = [hi[0].max(x), hi[1].max(y)];
        }
        let (x0, x1) = g.indices(0, lo[0], hi[0]);
        let (y0, y1) = g.indices(1, lo[1], hi[1]);
        let points = ((x1 - x0 + 1).max(0) as u64).saturating_mul((y1 - y0 + 1).max(0) as u64);
        if points > MAX_LATTICE_POINTS {
            return Err(FootprintError::TooLarge {
                pose: pose.to_string(),
                points,
                max: MAX_LATTICE_POINTS,
            });
        }
        Ok([(x0, x1), (y0, y1)])
    }

    /// Per lattice row of `lattice`: the hits inside the frame, and the elements seen outside it.
    /// Each pixel centre goes through `H^-1` to its wall element and footprint area (MODEL.md "From camera frames to i").
    fn hits(
        h: &Homography,
        wall: &Plane,
        geometry: Option<FrameGeometry>,
        g: &FrameGeometry,
        cells: Cells,
        lattice: [(i64, i64); 2],
    ) -> Vec<(Vec<Hit>, Vec<u32>)> {
        let [(x0, x1), (y0, y1)] = lattice;
        let (nu, nv) = (wall.grid.nu, wall.grid.nv);
        let inv = h.inverse_matrix();
        let det = h.inverse_determinant().abs();
        let element_of = |x: f64, y: f64| -> Option<(u32, f64, [f64; 2])> {
            let w = inv[2][0] * x + inv[2][1] * y + inv[2][2];
            let u = (inv[0][0] * x + inv[0][1] * y + inv[0][2]) / w;
            let v = (inv[1][0] * x + inv[1][1] * y + inv[1][2]) / w;
            let fu = (u / wall.size[0] + 0.5) * nu as f64;
            let fv = (v / wall.size[1] + 0.5) * nv as f64;
            (fu >= 0.0 && fv >= 0.0 && fu < nu as f64 && fv < nv as f64).then(|| {
                let j = (fv as usize).min(nv - 1) * nu + (fu as usize).min(nu - 1);
                (j as u32, det / (w * w * w).abs(), [u, v])
            })
        };
        let (width, height) = (g.size[0] as i64, g.size[1] as i64);
        let inside = |x: i64, y: i64| {
            geometry.is_none() || (0..width).contains(&x) && (0..height).contains(&y)
        };
        // A mosaic block, or a colour of a Bayer filter, sees its own cells'
        // pixels only (sensor coordinates are whole numbers there: such a
        // frame is not binned).
        let on_cell = |x: f64, y: f64| cells.contains(x.round() as i64, y.round() as i64);
        // Per lattice row: the hits inside the frame, and the elements seen outside it.
        (y0..=y1)
            .into_par_iter()
            .map(|yi| {
                let mut hits = Vec::new();
                let mut outside = Vec::new();
                let y = g.sensor(1, yi);
                if !cells.in_row(y.round() as i64) {
                    return (hits, outside);
                }
                for xi in x0..=x1 {
                    if !on_cell(g.sensor(0, xi), y) {
                        continue;
                    }
                    let Some((element, area, point)) = element_of(g.sensor(0, xi), y) else {
                        continue;
                    };
                    if inside(xi, yi) {
                        hits.push(Hit {
                            element,
                            pixel: if geometry.is_some() {
                                (yi * width + xi) as usize
                            } else {
                                0
                            },
                            area,
                            point,
                        });
                    } else {
                        outside.push(element);
                    }
                }
                (hits, outside)
            })
            .collect()
    }

    /// Pixels per wall element in `rows`, once every element holds one and none is cut by the frame.
    /// A mean over part of an element, or over none of it, would not be that element's `i_j`.
    fn counts(
        rows: &[(Vec<Hit>, Vec<u32>)],
        wall: &Plane,
        g: &FrameGeometry,
        pose: &str,
    ) -> Result<Vec<usize>, FootprintError> {
        let n = wall.grid.count();
        let mut counts = vec![0usize; n];
        let mut cut = vec![false; n];
        for (hits, outside) in rows {
            hits.iter().for_each(|h| counts[h.element as usize] += 1);
            outside.iter().for_each(|&e| cut[e as usize] = true);
        }
        if counts.iter().all(|&c| c == 0) {
            return Err(FootprintError::NoElement {
                pose: pose.to_string(),
                width: g.size[0],
                height: g.size[1],
            });
        }
        if let Some(j) = cut.iter().position(|&c| c) {
            let (iu, iv) = wall.grid.coords(j);
            return Err(FootprintError::OutsideFrame {
                pose: pose.to_string(),
                element: j,
                iu,
                iv,
                offset: g.offset,
                width: g.size[0],
                height: g.size[1],
                binning: g.binning,
            });
        }
        if let Some(j) = counts.iter().position(|&c| c == 0) {
            let (iu, iv) = wall.grid.coords(j);
            return Err(FootprintError::NoPixel {
                pose: pose.to_string(),
                element: j,
                iu,
                iv,
            });
        }
        Ok(counts)
    }

    /// The map in compressed rows from `rows`' hits, with weights `a_p / sum a_p` per element.
    /// Element-major order lets [`PixelMap::average`] sum each element's pixels in one slice.
    fn assemble(
        rows: Vec<(Vec<Hit>, Vec<u32>)>,
        counts: &[usize],
        geometry: Option<FrameGeometry>,
    ) -> Self {
        let n = counts.len();
        let mut starts = Vec::with_capacity(n + 1);
        starts.push(0);
        for c in counts {
            starts.push(starts[starts.len() - 1] + c);
        }
        let total = starts[n];
        let mut next = starts[..n].to_vec();
        let mut pixels = vec![0usize; if geometry.is_some() { total } else { 0 }];
        let mut weights = vec![0.0; total];
        let mut pts = vec![[0.0; 2]; if geometry.is_some() { 0 } else { total }];
        for (hits, _) in rows {
            for hit in hits {
                let e = hit.element as usize;
                let k = next[e];
                next[e] += 1;
                weights[k] = hit.area;
                if geometry.is_some() {
                    pixels[k] = hit.pixel;
                } else {
                    pts[k] = hit.point;
                }
            }
        }
        for j in 0..n {
            let r = starts[j]..starts[j + 1];
            let sum: f64 = weights[r.clone()].iter().sum();
            weights[r].iter_mut().for_each(|w| *w /= sum);
        }
        Self {
            starts,
            pixels,
            weights,
            points: pts,
            geometry,
        }
    }
}

/// Every row's effective number of pixels (MODEL.md row order: each block
/// repeats its pose's elements): how many pixels' photons a measurement
/// from camera frames averages into each value. `None` when a pose has no
/// homography (its measurement is not made from frames).
pub fn effective_pixels(scene: &super::Scene) -> Result<Option<Vec<f64>>, FootprintError> {
    let plane = &scene.wall().plane;
    let mut out = Vec::with_capacity(scene.rows());
    for pose in scene.poses() {
        let Some(h) = pose.homography.as_ref() else {
            return Ok(None);
        };
        let cells: Vec<Option<[u32; 2]>> = if pose.analyzers.is_empty() {
            vec![None]
        } else {
            pose.analyzers.iter().map(|a| a.cell).collect()
        };
        // One map per pixel lattice: a sheet's angles share the pose's.
        let mut made: Vec<(Option<[u32; 2]>, Vec<f64>)> = Vec::new();
        for cell in cells {
            if !made.iter().any(|(c, _)| *c == cell) {
                let map = PixelMap::cell_plane(h, plane, cell.into(), &pose.name)?;
                made.push((
                    cell,
                    (0..map.elements())
                        .map(|j| map.effective_pixels(j))
                        .collect(),
                ));
            }
            if let Some((_, rows)) = made.iter().find(|(c, _)| *c == cell) {
                out.extend_from_slice(rows);
            }
        }
    }
    Ok(Some(out))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bench() -> (Homography, Plane) {
        let s = crate::scene::Scene::builtin("brewster-crossed")
            .and_then(Result::ok)
            .expect("built-in scene");
        (
            s.poses()[0].homography.expect("pose A has a homography"),
            s.wall().plane.clone(),
        )
    }

    /// The assignment by brute force: every pixel of the frame, one at a time.
    fn brute(h: &Homography, wall: &Plane, g: FrameGeometry) -> Vec<Vec<(usize, f64)>> {
        let mut out = vec![Vec::new(); wall.grid.count()];
        let m = h.inverse_matrix();
        for y in 0..g.size[1] {
            for x in 0..g.size[0] {
                let sx = g.sensor(0, x as i64);
                let sy = g.sensor(1, y as i64);
                let (u, v) = h.invert(sx, sy).expect("finite");
                let fu = (u / wall.size[0] + 0.5) * wall.grid.nu as f64;
                let fv = (v / wall.size[1] + 0.5) * wall.grid.nv as f64;
                if fu >= 0.0 && fv >= 0.0 && fu < wall.grid.nu as f64 && fv < wall.grid.nv as f64 {
                    let w = m[2][0] * sx + m[2][1] * sy + m[2][2];
                    let a = h.inverse_determinant().abs() / w.abs().powi(3);
                    out[wall.grid.index(fu as usize, fv as usize)].push((y * g.size[0] + x, a));
                }
            }
        }
        out
    }

    #[test]
    fn an_element_with_a_saturated_pixel_is_not_measured_and_the_others_are_unchanged() {
        let (h, wall) = bench();
        let g = FrameGeometry::plain(512, 512);
        let map = PixelMap::frame(&h, &wall, g, "A").expect("the wall is in the frame");
        // Every pixel reads 100 except element 0's first pixel (a lower
        // bound: NaN); variance 4 everywhere.
        let mut values = vec![100.0f32; 512 * 512];
        values[map.pixels[map.range(0).start]] = f32::NAN;
        let (means, vars) = map.average(&values, Some(&|_| 4.0));
        let vars = vars.expect("variance given");
        assert!(means[0].is_nan() && vars[0].is_nan());
        let w1: f64 = map.range(1).map(|k| map.weights[k].powi(2) * 4.0).sum();
        assert!((means[1] - 100.0).abs() < 1e-9, "{}", means[1]);
        assert_eq!(vars[1], w1);
    }

    #[test]
    fn one_colours_interpolated_mean_of_a_linear_frame_is_the_whole_mean() {
        let (h, wall) = bench();
        let g = FrameGeometry {
            offset: [2, 4],
            size: [512, 512],
            binning: [1, 1],
        };
        let map = PixelMap::frame(&h, &wall, g, "A").expect("the wall is in the frame");
        // A linear gradient: every pixel's interpolation from its
        // neighbours of one colour is exact, so is each element's mean.
        let values: Vec<f32> = (0..512 * 512)
            .map(|p| (1000 + 3 * (p % 512) + 5 * (p / 512)) as f32)
            .collect();
        let (whole, _) = map.average(&values, None);
        let red = Cells::one([1, 0]);
        let green = Cells::any(&[[0, 0], [1, 1]]);
        for cells in [red, green] {
            let m = map.interpolated(cells).expect("an unbinned frame map");
            assert_eq!(m.elements(), map.elements());
            // Only that colour's pixels carry weight, summing to 1 per element.
            let sx = |p: usize| 2 + (p % 512) as i64;
            let sy = |p: usize| 4 + (p / 512) as i64;
            assert!(m.pixels.iter().all(|&p| cells.contains(sx(p), sy(p))));
            for j in 0..m.elements() {
                let sum: f64 = m.range(j).map(|k| m.weights[k]).sum();
                assert!((sum - 1.0).abs() < 1e-12, "{sum}");
            }
            let (means, _) = m.average(&values, None);
            let worst = means
                .iter()
                .zip(&whole)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            // Interior elements exactly; an element at the wall's edge
            // interpolates one-sided there (measured: a fraction of a DN).
            let interior = (0..wall.grid.nv)
                .flat_map(|v| (0..wall.grid.nu).map(move |u| (u, v)))
                .filter(|&(u, v)| u > 0 && v > 0 && u + 1 < wall.grid.nu && v + 1 < wall.grid.nv)
                .map(|(u, v)| (means[wall.grid.index(u, v)] - whole[wall.grid.index(u, v)]).abs())
                .fold(0.0, f64::max);
            assert!(interior < 1e-6, "{interior}");
            assert!(worst < 3.0, "{worst}");
        }
        // The plain mean over red's own pixels is off by the half pixel.
        let plain = PixelMap::cell_frame(&h, &wall, g, red, "A").expect("red pixels");
        let (means, _) = plain.average(&values, None);
        assert!((means[100] - whole[100]).abs() > 1.0);
        let binned = FrameGeometry {
            binning: [2, 2],
            size: [256, 256],
            offset: [0, 0],
        };
        let map = PixelMap::frame(&h, &wall, binned, "A").expect("binned");
        assert!(map.interpolated(red).is_none());
    }

    #[test]
    fn every_pixel_of_the_bench_frame_goes_to_the_element_it_images() {
        let (h, wall) = bench();
        let g = FrameGeometry::plain(512, 512);
        let map = PixelMap::frame(&h, &wall, g, "A").expect("the wall is in the frame");
        let want = brute(&h, &wall, g);
        let counts: Vec<usize> = (0..map.elements()).map(|j| map.range(j).len()).collect();
        for (j, w) in want.iter().enumerate() {
            assert_eq!(counts[j], w.len(), "element {j}");
            let sum: f64 = w.iter().map(|p| p.1).sum();
            for (k, &(p, a)) in map.range(j).zip(w) {
                assert_eq!(map.pixels[k], p);
                assert!((map.weights[k] - a / sum).abs() < 1e-12);
            }
        }
        // The reference bench: dozens to ~170 pixels an element (MODEL.md
        // quotes 38-167, median 73), 84 348 in all.
        let mut sorted = counts.clone();
        sorted.sort_unstable();
        let median = sorted[sorted.len() / 2];
        assert_eq!((sorted[0], sorted[sorted.len() - 1]), (36, 168));
        assert!((60..=80).contains(&median), "{median}");
        assert!((80_000..90_000).contains(&map.len()), "{}", map.len());
    }

    #[test]
    fn footprints_are_the_jacobian_of_the_inverse_homography() {
        // A pure scale: 1 mm per pixel, footprint 1e-6 m^2 everywhere.
        let h = Homography::new([[1000.0, 0.0, 50.0], [0.0, 1000.0, 50.0], [0.0, 0.0, 1.0]])
            .expect("invertible");
        assert!((h.inverse_determinant().abs() - 1e-6).abs() < 1e-18);
        let wall = Plane {
            center: crate::optics::Vec3::zeros(),
            normal: crate::optics::Vec3::z(),
            u: crate::optics::Vec3::x(),
            v: crate::optics::Vec3::y(),
            size: [0.1, 0.1],
            grid: crate::scene::Grid { nu: 2, nv: 2 },
            supersample: 1,
        };
        let map = PixelMap::plane(&h, &wall, "P").expect("in view");
        // 100 x 100 lattice points in [0, 100)^2 hit the wall: 50 x 50 per element.
        assert_eq!(map.len(), 10_000);
        assert!((0..4).all(|j| map.range(j).len() == 2500));
        assert!(map
            .weights()
            .iter()
            .all(|w| (w - 1.0 / 2500.0).abs() < 1e-15));
        let p = map.points()[map.range(0).start];
        assert!(
            (p[0] + 0.05).abs() < 1e-12 && (p[1] + 0.05).abs() < 1e-12,
            "{p:?}"
        );
    }

    #[test]
    fn binning_and_offsets_place_pixels_on_the_sensor() {
        let (h, wall) = bench();
        // A 2x2-binned 256x256 frame of the whole sensor: each binned pixel
        // centre sits at (2X + 0.5, 2Y + 0.5).
        let g = FrameGeometry {
            offset: [0, 0],
            size: [256, 256],
            binning: [2, 2],
        };
        let map = PixelMap::frame(&h, &wall, g, "A").expect("whole wall");
        let want = brute(&h, &wall, g);
        for (j, w) in want.iter().enumerate() {
            assert_eq!(map.range(j).len(), w.len(), "element {j}");
        }
        let whole =
            PixelMap::frame(&h, &wall, FrameGeometry::plain(512, 512), "A").expect("whole wall");
        let ratio = whole.len() as f64 / map.len() as f64;
        assert!((ratio - 4.0).abs() < 0.1, "{ratio}");
    }

    #[test]
    fn a_frame_that_cuts_the_wall_names_an_element_and_the_pose() {
        let (h, wall) = bench();
        let g = FrameGeometry {
            offset: [100, 0],
            size: [300, 512],
            binning: [1, 1],
        };
        let e = PixelMap::frame(&h, &wall, g, "A").unwrap_err();
        assert!(matches!(e, FootprintError::OutsideFrame { .. }), "{e}");
        assert!(e.to_string().starts_with("pose \"A\": wall element"), "{e}");
        // A frame far from the wall's image holds no element at all.
        let g = FrameGeometry {
            offset: [0, 0],
            size: [4, 4],
            binning: [1, 1],
        };
        let e = PixelMap::frame(&h, &wall, g, "A").unwrap_err();
        assert!(matches!(e, FootprintError::NoElement { .. }), "{e}");
    }

    #[test]
    fn an_element_smaller_than_a_pixel_is_named() {
        let (h, mut wall) = bench();
        wall.grid = crate::scene::Grid { nu: 1024, nv: 1024 };
        let e = PixelMap::plane(&h, &wall, "A").unwrap_err();
        assert!(matches!(e, FootprintError::NoPixel { .. }), "{e}");
    }

    #[test]
    fn a_homography_that_sees_the_wall_edge_on_is_refused_before_allocating() {
        let (_, wall) = bench();
        let h = Homography::new([[1e9, 0.0, 0.0], [0.0, 1e9, 0.0], [0.0, 0.0, 1.0]])
            .expect("invertible");
        let e = PixelMap::plane(&h, &wall, "A").unwrap_err();
        assert!(matches!(e, FootprintError::TooLarge { .. }), "{e}");
        // The horizon crosses the wall: a corner maps behind the camera.
        let h = Homography::new([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [10.0, 0.0, 1.0]])
            .expect("invertible");
        let e = PixelMap::plane(&h, &wall, "A").unwrap_err();
        assert!(matches!(e, FootprintError::NotInView { .. }), "{e}");
    }
}
