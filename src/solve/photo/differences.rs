//! The differenced data term's operators: `D T` and `D i` (first
//! differences of each block's wall image, which cancel a constant
//! background), and the rows they drop or centre.

use super::*;

/// `D T`: each column's first differences along u (`rows` of a block) then
/// along v, block by block, as `gradient` lays them out; each block of `T`
/// becomes two blocks of `D T` with its label (u-differences, v-differences).
/// The last column's u-differences and the last row's v-differences are 0
/// (Neumann), rows that carry no data and weigh nothing.
pub fn differences(t: &Transport) -> Transport {
    let grid = t.wall_grid();
    let nw = grid.count();
    let rows = 2 * t.rows();
    let mut data = vec![0.0; rows * t.cols()];
    data.par_chunks_mut(rows.max(1))
        .enumerate()
        .for_each(|(k, out)| {
            for (col, out) in t.col(k).chunks(nw).zip(out.chunks_mut(2 * nw)) {
                gradient(grid, col, out);
            }
        });
    let blocks = t
        .blocks()
        .iter()
        .flat_map(|b| [b.clone(), b.clone()])
        .collect();
    Transport::from_col_major(rows, t.cols(), data, blocks, grid, t.scene_grid())
}

/// `D i` laid out as [`differences`] lays out `D T`.
pub(crate) fn difference_values(t: &Transport, i: &[f64]) -> Vec<f64> {
    let nw = t.wall_grid().count();
    let mut out = vec![0.0; 2 * i.len()];
    for (b, o) in i.chunks(nw).zip(out.chunks_mut(2 * nw)) {
        gradient(t.wall_grid(), b, o);
    }
    out
}

/// Rows of `D T` that carry data: `(nu - 1) nv + nu (nv - 1)` per block.
pub(super) fn difference_rows(t: &Transport) -> usize {
    let g = t.wall_grid();
    t.blocks().len() * (g.nu.saturating_sub(1) * g.nv + g.nu * g.nv.saturating_sub(1))
}

/// The rows of the data term's matrix that touch a `gone` row of `T`: for
/// differences, `(D i)_r` with either of its two rows gone; for raw values,
/// the row itself.
pub(super) fn dropped_rows(t: &Transport, data_term: DataTerm, gone: &[bool]) -> Vec<usize> {
    if !gone.iter().any(|g| *g) {
        return Vec::new();
    }
    match data_term {
        DataTerm::Values => (0..gone.len()).filter(|&j| gone[j]).collect(),
        DataTerm::Differences => {
            let g = t.wall_grid();
            let nw = g.count();
            let mut out = Vec::new();
            for b in 0..t.blocks().len() {
                let base = b * nw;
                for iv in 0..g.nv {
                    for iu in 0..g.nu {
                        let j = g.index(iu, iv);
                        let here = gone[base + j];
                        if iu + 1 < g.nu && (here || gone[base + j + 1]) {
                            out.push(2 * base + j);
                        }
                        if iv + 1 < g.nv && (here || gone[base + j + g.nu]) {
                            out.push(2 * base + nw + j);
                        }
                    }
                }
            }
            out.sort_unstable();
            out
        }
    }
}

/// Whether row `r` of the data term's matrix carries data when every row
/// of `T` is measured (the Neumann edge differences do not).
pub(super) fn carries_data(t: &Transport, data_term: DataTerm, r: usize) -> bool {
    match data_term {
        DataTerm::Values => true,
        DataTerm::Differences => {
            let g = t.wall_grid();
            let nw = g.count();
            let within = r % (2 * nw);
            let (j, along_v) = match within < nw {
                true => (within, false),
                false => (within - nw, true),
            };
            let (iu, iv) = (j % g.nu, j / g.nu);
            match along_v {
                false => iu + 1 < g.nu,
                true => iv + 1 < g.nv,
            }
        }
    }
}

/// `i` less each block's mean: with the same done to `T`'s columns
/// ([`centred_columns`]) the background drops out of a raw-value fit exactly
/// (its least-squares value is the block's mean residual).
pub(super) fn centred(t: &Transport, i: &[f64]) -> Vec<f64> {
    centred_masked(t, i, &vec![false; i.len()])
}

/// [`centred`] over the rows not `gone` (each block's mean of those), the
/// `gone` rows 0.
pub(super) fn centred_masked(t: &Transport, i: &[f64], gone: &[bool]) -> Vec<f64> {
    let nw = t.wall_grid().count();
    i.chunks(nw)
        .zip(gone.chunks(nw))
        .flat_map(|(b, g)| {
            let kept = g.iter().filter(|g| !**g).count().max(1);
            let sum: f64 = b.iter().zip(g).filter(|(_, g)| !**g).map(|(v, _)| v).sum();
            let m = sum / kept as f64;
            b.iter()
                .zip(g)
                .map(move |(v, g)| if *g { 0.0 } else { v - m })
        })
        .collect()
}

/// `T` with each column's mean over each block's rows not `gone` taken out.
pub(super) fn centred_columns(t: &Transport, gone: &[bool]) -> Transport {
    let mut data = Vec::with_capacity(t.rows() * t.cols());
    for k in 0..t.cols() {
        data.extend(centred_masked(t, t.col(k), gone));
    }
    Transport::from_col_major(
        t.rows(),
        t.cols(),
        data,
        t.blocks().to_vec(),
        t.wall_grid(),
        t.scene_grid(),
    )
}
