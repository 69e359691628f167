//! The tracker of live view's difference mode: where the moving object is
//! in a difference image, as the centroid of its bright part on the
//! hidden-scene plane, with the centroid's standard deviation.
//!
//! The object is the peak's element and those above [`LEVEL`] of the peak
//! joined to it (side or corner), each weighted by how far it is above
//! that level (so an element that enters or leaves the object moves the
//! centroid smoothly, not by a jump); one object, the brightest.
//!
//! The centroid's standard deviation has two shares, added in quadrature.
//! The noise's: the elements' noise propagated through that weighted mean,
//! to first order with the level held, `sigma^2 sum_j (u_j - u)^2 / W^2`
//! over the object's elements, `W` their summed weight. The grid's:
//! `du^2 / 12`, `du` an element's size along u (likewise v), the error of
//! rounding to a whole element. Why the grid's share: a TV reconstruction
//! gathers an object's mass into whole elements, so its centroid moves in
//! steps while the object moves smoothly (on the moving fake bench the
//! centroid's error was 0.3 elements RMS where the noise's share alone was
//! under a tenth of it); without it the deviation would claim a precision
//! the images do not have.
//!
//! The noise `sigma` is the median of the positive elements away from the
//! object (neither in it nor next to it) over 0.6745. Why those: a
//! difference image is zero where nothing changed, but for its noise and
//! for the trail the background keeps of the object's past positions,
//! which is negative (subtracted); the object's dim edge is next to it.
//! What is left on the positive side is noise, and for Gaussian noise the
//! median of its positive half is 0.6745 of its standard deviation. Why the
//! median: a corner element the wall hardly sees comes back from the
//! reconstruction as a lone artefact as bright as the object's edge, and an
//! RMS counted it as noise. The spread of the bright part is the object's
//! size, not how well its centre is known.
//!
//! Whether anything moved is the measurement's to say where it can: a
//! difference whose chi-square against its noise stands out (the
//! progressive solver's judgement, with the measured variance) has an
//! object, the brightest blob however faint; one that does not has none.
//! Only without a variance to judge by (a window of one frame) does the
//! image decide: a peak under [`DETECTION`] times the noise is no object.
//! Why not the image always: the reconstruction's artefacts (a corner
//! element the wall hardly sees) are not noise, and on the moving fake
//! bench they hid the object from an image-only test in one result in
//! twenty.

use serde::Serialize;

use crate::scene::Plane;

/// The moving object's centroid in one result of difference mode, on the
/// hidden-scene plane (metres from its centre along its u and v axes,
/// MODEL.md "Geometry of a scene file"), with the centroid's standard
/// deviation: the image's noise away from the object propagated through
/// the centroid, and the grid's share, an element over the root of 12 (the
/// tracker's rule: [`centroid`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Centroid {
    /// Along u, metres.
    pub u_m: f64,
    /// Along v, metres.
    pub v_m: f64,
    /// Standard deviation along u, metres.
    pub sigma_u_m: f64,
    /// Standard deviation along v, metres.
    pub sigma_v_m: f64,
}

/// Fraction of the peak an element of the object is above.
const LEVEL: f64 = 0.5;

/// How many times the noise its peak must be for an object to be one.
/// Why 3: Gaussian noise alone passes it at 0.13 % of elements (one 8 x 8
/// image in twelve), and the fake bench's object stood at 4 to 6 times it.
const DETECTION: f64 = 3.0;

/// The median of a Gaussian's absolute value, in standard deviations.
const HALF_NORMAL_MEDIAN: f64 = 0.6745;

/// The moving object's centroid in a difference `image` on `plane`'s grid
/// (`colours` values per element, interleaved, summed); `None` when
/// nothing moved: `moved` is the measurement's judgement, `None` for the
/// image's.
pub(crate) fn centroid(
    image: &[f64],
    colours: usize,
    plane: &Plane,
    moved: Option<bool>,
) -> Option<Centroid> {
    if moved == Some(false) {
        return None;
    }
    let (nu, nv) = (plane.grid.nu, plane.grid.nv);
    let c = colours.max(1);
    if nu * nv == 0 || image.len() != nu * nv * c {
        return None;
    }
    let values: Vec<f64> = image.chunks(c).map(|e| e.iter().sum()).collect();
    let (top, peak) = values
        .iter()
        .copied()
        .enumerate()
        .filter(|(_, v)| v.is_finite())
        .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
    if peak <= 0.0 {
        return None;
    }
    let level = LEVEL * peak;
    let object = joined(&values, top, level, nu);
    let noise = noise_away_from(&values, &object, nu)?;
    if moved.is_none() && peak < DETECTION * noise {
        return None;
    }
    // Each element's centre on the plane, metres from its centre.
    let at = |j: usize| {
        let (iu, iv) = (j % nu, j / nu);
        (
            ((iu as f64 + 0.5) / nu as f64 - 0.5) * plane.size[0],
            ((iv as f64 + 0.5) / nv as f64 - 0.5) * plane.size[1],
        )
    };
    let members: Vec<(f64, (f64, f64))> = (0..values.len())
        .filter(|&j| object[j])
        .map(|j| (values[j] - level, at(j)))
        .collect();
    let w: f64 = members.iter().map(|m| m.0).sum();
    let u = members.iter().map(|(x, p)| x * p.0).sum::<f64>() / w;
    let v = members.iter().map(|(x, p)| x * p.1).sum::<f64>() / w;
    let spread = |d: &dyn Fn(&(f64, f64)) -> f64| {
        members
            .iter()
            .map(|(_, p)| d(p).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let (du, dv) = (plane.size[0] / nu as f64, plane.size[1] / nv as f64);
    Some(Centroid {
        u_m: u,
        v_m: v,
        sigma_u_m: (noise * spread(&|p| p.0 - u) / w).hypot(du / 12f64.sqrt()),
        sigma_v_m: (noise * spread(&|p| p.1 - v) / w).hypot(dv / 12f64.sqrt()),
    })
}

/// The elements above `level` joined to element `top` (side or corner),
/// `top` among them, in an image of rows of `nu`.
fn joined(values: &[f64], top: usize, level: f64, nu: usize) -> Vec<bool> {
    let nv = values.len() / nu;
    let mut object = vec![false; values.len()];
    object[top] = true;
    let mut todo = vec![top];
    while let Some(j) = todo.pop() {
        let (iu, iv) = (j % nu, j / nu);
        for v in iv.saturating_sub(1)..(iv + 2).min(nv) {
            for u in iu.saturating_sub(1)..(iu + 2).min(nu) {
                let k = v * nu + u;
                if !object[k] && values[k] > level {
                    object[k] = true;
                    todo.push(k);
                }
            }
        }
    }
    object
}

/// The noise of `values` (rows of `nu`): the median of its positive
/// elements that are neither in `object` nor next to it over
/// [`HALF_NORMAL_MEDIAN`] (0 when there are none); `None` when the object
/// reaches every element.
/// Why: see the module's account of the noise.
fn noise_away_from(values: &[f64], object: &[bool], nu: usize) -> Option<f64> {
    let nv = values.len() / nu;
    let near = |j: usize| {
        let (iu, iv) = ((j % nu) as i64, (j / nu) as i64);
        (-1..=1).any(|dv: i64| {
            (-1..=1).any(|du: i64| {
                let (u, v) = (iu + du, iv + dv);
                (0..nu as i64).contains(&u)
                    && (0..nv as i64).contains(&v)
                    && object[(v * nu as i64 + u) as usize]
            })
        })
    };
    let away: Vec<f64> = (0..values.len())
        .filter(|&j| values[j].is_finite() && !near(j))
        .map(|j| values[j])
        .collect();
    // An image that changed everywhere (the light went on) has no object.
    if away.is_empty() {
        return None;
    }
    let mut positive: Vec<f64> = away.into_iter().filter(|&x| x > 0.0).collect();
    positive.sort_by(f64::total_cmp);
    let n = positive.len();
    let median = match n {
        0 => 0.0,
        _ if n % 2 == 1 => positive[n / 2],
        _ => 0.5 * (positive[n / 2 - 1] + positive[n / 2]),
    };
    Some(median / HALF_NORMAL_MEDIAN)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optics::Vec3;
    use crate::scene::Grid;

    /// An 8 x 8 plane of 0.2 m, as the demo scene's: 25 mm elements.
    fn plane() -> Plane {
        Plane {
            center: Vec3::zeros(),
            normal: Vec3::z(),
            u: Vec3::x(),
            v: Vec3::y(),
            size: [0.2, 0.2],
            grid: Grid { nu: 8, nv: 8 },
            supersample: 1,
        }
    }

    /// A blob of `peak` over elements at distance d from (u, v) in metres,
    /// `exp(-d^2 / 2 s^2)`, on the 8 x 8 plane.
    fn blob(u: f64, v: f64, peak: f64) -> Vec<f64> {
        (0..64)
            .map(|j| {
                let (eu, ev) = (
                    ((j % 8) as f64 + 0.5) * 0.025 - 0.1,
                    ((j / 8) as f64 + 0.5) * 0.025 - 0.1,
                );
                let d2 = (eu - u).powi(2) + (ev - v).powi(2);
                peak * (-d2 / (2.0 * 0.02f64.powi(2))).exp()
            })
            .collect()
    }

    #[test]
    fn a_blob_s_centroid_is_where_it_is_in_metres_and_the_brightest_of_two_is_the_object() {
        // On an element centre: exact, whatever the noise (none here).
        let c = centroid(&blob(0.0125, -0.0375, 2.0), 1, &plane(), None).expect("an object");
        assert!(
            (c.u_m - 0.0125).abs() < 1e-12 && (c.v_m + 0.0375).abs() < 1e-12,
            "{c:?}"
        );
        // Between element centres: within a tenth of an element (2.5 mm).
        for (u, v) in [(0.02, 0.03), (-0.051, 0.007), (0.0, 0.0)] {
            let c = centroid(&blob(u, v, 1.0), 1, &plane(), None).expect("an object");
            assert!(
                (c.u_m - u).abs() < 2.5e-3 && (c.v_m - v).abs() < 2.5e-3,
                "({u}, {v}): {c:?}"
            );
            // The grid's share (an element over the root of 12) and a
            // little of the noise's (the blob's tail away from it counts).
            let grid = 0.025 / 12f64.sqrt();
            assert!(c.sigma_u_m >= grid && c.sigma_u_m < 1.2 * grid, "{c:?}");
            assert!(c.sigma_v_m >= grid && c.sigma_v_m < 1.2 * grid, "{c:?}");
        }
        // A dimmer blob elsewhere is not the object.
        let two: Vec<f64> = blob(0.05, 0.05, 1.0)
            .iter()
            .zip(blob(-0.05, -0.05, 0.6))
            .map(|(a, b)| a + b)
            .collect();
        let c = centroid(&two, 1, &plane(), None).expect("an object");
        assert!(
            (c.u_m - 0.05).abs() < 3e-3 && (c.v_m - 0.05).abs() < 3e-3,
            "{c:?}"
        );
        // Colours add up: three equal colours give the grey answer.
        let grey = blob(0.02, 0.03, 1.0);
        let rgb: Vec<f64> = grey.iter().flat_map(|&x| [x, x, x]).collect();
        let (a, b) = (
            centroid(&rgb, 3, &plane(), None).unwrap(),
            centroid(&grey, 1, &plane(), None).unwrap(),
        );
        assert!((a.u_m - b.u_m).abs() < 1e-12 && (a.v_m - b.v_m).abs() < 1e-12);
    }

    #[test]
    fn the_centroid_s_spread_is_the_noise_propagated_and_noise_alone_is_no_object() {
        // A single bright element on +-0.1 noise: the object is that element
        // (and any noise above half its peak); the noise is measured.
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut noise = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            0.1 * ((rng >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) * 3f64.sqrt()
        };
        let clean = blob(0.0, 0.0, 1.0);
        let noisy: Vec<f64> = clean.iter().map(|&x| x + noise()).collect();
        let a = centroid(&clean, 1, &plane(), None).unwrap();
        let b = centroid(&noisy, 1, &plane(), None).unwrap();
        assert!(
            b.sigma_u_m > a.sigma_u_m && b.sigma_v_m > a.sigma_v_m,
            "{a:?} {b:?}"
        );
        // The noise moved the centroid by about its spread, not by more than 3 of them.
        let off = (b.u_m - a.u_m).hypot(b.v_m - a.v_m);
        assert!(off < 3.0 * b.sigma_u_m.hypot(b.sigma_v_m), "{off} {b:?}");
        // A lone bright corner (an element the wall hardly sees) is not
        // taken for noise that would hide the object.
        let mut corner = noisy.clone();
        corner[0] = 0.45;
        let c = centroid(&corner, 1, &plane(), None).expect("the object still stands out");
        assert!((c.u_m - b.u_m).abs() < 1e-12 && (c.v_m - b.v_m).abs() < 1e-12);
        // Noise alone, a flat image, nothing: no object.
        let alone: Vec<f64> = (0..64).map(|_| noise()).collect();
        assert!(centroid(&alone, 1, &plane(), None).is_none());
        // The measurement's judgement wins: a change is the brightest blob
        // however faint in the image, no change is no object.
        assert!(centroid(&alone, 1, &plane(), Some(true)).is_some());
        assert!(centroid(&noisy, 1, &plane(), Some(false)).is_none());
        assert!(centroid(&[0.0; 64], 1, &plane(), None).is_none());
        assert!(centroid(&[-1.0; 64], 1, &plane(), None).is_none());
        assert!(centroid(&[1.0; 64], 1, &plane(), None).is_none());
        // An image of another size than the grid: no answer rather than a wrong one.
        assert!(centroid(&[1.0; 10], 1, &plane(), None).is_none());
    }
}
