//! The quadrature points' sums onto the nodes (forces, Hessian products, assembled
//! blocks), in parallel and in a fixed order.
//!
//! A point adds to the rows of the 3 x 3 x 3 nodes of its stencil, from its base node on.
//! The region's nodes are numbered in the order of their grid index (x-major), so the
//! nodes of a range of x-layers are a range of rows. The points are grouped in *slabs*
//! by the x-layer of their base, [`LAYERS`] layers a slab; a slab's points reach the
//! layers of its bases and the two after them, so two slabs with one between them write
//! disjoint ranges of rows. The even slabs are summed at once, each into its own rows,
//! then the odd ones: every row adds its points' terms in one order (its even slab's
//! points in their order, then its odd slab's), whatever the number of threads, and the
//! sums are the same to the bit on any of them.

use rayon::prelude::*;

/// x-layers of bases per slab (at least two, for slabs of one parity to be disjoint).
const LAYERS: usize = 4;

/// The region's points grouped by slab, and the rows each slab reaches.
#[derive(Clone, Default)]
pub(super) struct Slabs {
    /// The points (region point indices) slab by slab: slab `s`'s are
    /// `points[starts[s]..starts[s + 1]]`, in ascending order.
    points: Vec<u32>,
    starts: Vec<usize>,
    /// Per slab, the first row it reaches and the one after its last.
    rows: Vec<(usize, usize)>,
}

impl Slabs {
    /// The slabs of points whose stencils have their base at x-layer `base_x[r]` (region
    /// point `r`), over region nodes at x-layers `node_x` (ascending: the region's
    /// numbering).
    pub fn new(base_x: &[i32], node_x: &[i32]) -> Slabs {
        assert!(
            node_x.windows(2).all(|w| w[0] <= w[1]),
            "nodes out of order"
        );
        let Some(&lowest) = base_x.iter().min() else {
            return Slabs {
                starts: vec![0],
                ..Default::default()
            };
        };
        let slab = |x: i32| (x - lowest) as usize / LAYERS;
        let count = slab(*base_x.iter().max().unwrap()) + 1;
        let mut starts = vec![0; count + 1];
        for &x in base_x {
            starts[slab(x) + 1] += 1;
        }
        for s in 0..count {
            starts[s + 1] += starts[s];
        }
        let mut points = vec![0; base_x.len()];
        let mut next = starts.clone();
        for (r, &x) in base_x.iter().enumerate() {
            let s = slab(x);
            points[next[s]] = r as u32;
            next[s] += 1;
        }
        let row = |x: i32| node_x.partition_point(|&n| n < x);
        let rows = (0..count)
            .map(|s| {
                let first = lowest + (s * LAYERS) as i32;
                (row(first), row(first + LAYERS as i32 + 2))
            })
            .collect();
        Slabs {
            points,
            starts,
            rows,
        }
    }

    /// Adds every point's terms to `out` (`width` entries per row): `add(points, rows,
    /// first)` adds those of a slab's `points` (region point indices, in order) to `rows`,
    /// the rows of the slab from row `first` on (`rows[width * (d - first)..]` is row
    /// `d`'s). The even slabs run in parallel, then the odd ones.
    pub fn add<T: Send>(
        &self,
        out: &mut [T],
        width: usize,
        add: impl Fn(&[u32], &mut [T], usize) + Sync,
    ) {
        for parity in 0..2 {
            let mut parts = Vec::new();
            let (mut rest, mut at) = (&mut *out, 0);
            for s in (parity..self.rows.len()).step_by(2) {
                let (first, end) = self.rows[s];
                let (_, tail) = std::mem::take(&mut rest).split_at_mut(width * (first - at));
                let (mine, tail) = tail.split_at_mut(width * (end - first));
                parts.push((s, mine, first));
                (rest, at) = (tail, end);
            }
            parts.into_par_iter().for_each(|(s, rows, first)| {
                add(
                    &self.points[self.starts[s]..self.starts[s + 1]],
                    rows,
                    first,
                );
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Random points on a grid of 21 x-layers (3 nodes a layer): the slabs' sums equal the
    /// sequential ones (integers, so exactly), to the bit on 1 to 3 threads, and a point
    /// never reaches outside its slab's rows.
    #[test]
    fn slabs_add_every_point_once_into_its_own_rows() {
        let node_x: Vec<i32> = (0..21).flat_map(|x| [x, x, x]).collect();
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as i32
        };
        let base_x: Vec<i32> = (0..500).map(|_| next() % 21 - 2).collect();
        let value: Vec<f64> = (0..500).map(|_| (next() % 100) as f64).collect();
        // Point `r` adds `value[r]` to each existing node of its layers `base..base + 2`.
        let (nodes, bases) = (&node_x, &base_x);
        let reached = move |r: usize| {
            (0..nodes.len()).filter(move |&d| (bases[r]..bases[r] + 3).contains(&nodes[d]))
        };
        let mut expected = vec![0.0; 2 * node_x.len()];
        for r in 0..500 {
            for d in reached(r) {
                expected[2 * d] += value[r];
                expected[2 * d + 1] += 1.0;
            }
        }
        let slabs = Slabs::new(&base_x, &node_x);
        let sums: Vec<Vec<f64>> = (1..=3)
            .map(|threads| {
                let mut out = vec![0.0; 2 * node_x.len()];
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                pool.install(|| {
                    slabs.add(&mut out, 2, |slab, rows, first| {
                        for &r in slab {
                            for d in reached(r as usize) {
                                assert!(d >= first && 2 * (d - first) < rows.len(), "point {r}");
                                rows[2 * (d - first)] += value[r as usize];
                                rows[2 * (d - first) + 1] += 1.0;
                            }
                        }
                    })
                });
                out
            })
            .collect();
        assert!(expected.iter().any(|&v| v > 0.0));
        for out in &sums {
            assert_eq!(out, &expected);
        }
    }
}
