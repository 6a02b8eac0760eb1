//! The dense algebra a wide contact's solve is made of, on one thread: a Cholesky
//! factorisation in single and double precision, an LU factorisation with partial
//! pivoting (what a Newton step on a system that is not symmetric would factor) and a
//! product with a vector, at the sizes of the linear gel's contact systems (3 unknowns a
//! node column: 100 columns, 200, and the 322 of a gripper pad's whole face). It bounds
//! from below what a solve of such a contact can cost (`docs/rl.md`, "The coupled
//! grasp's floor, by object").
//!
//! `cargo bench --bench dense`: the best of 20 runs of each, in milliseconds.

use std::time::Instant;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt;
use faer::{Mat, Par};

/// A symmetric positive definite matrix of order `n`, as dense as a compliance.
fn spd<T: faer::traits::RealField + Copy + From<f32>>(n: usize) -> Mat<T> {
    let a = Mat::<T>::from_fn(n, n, |i, j| {
        T::from(((i * 7 + j * 13) % 17) as f32 / 17.0 - 0.5)
    });
    let mut s = &a * a.transpose();
    for i in 0..n {
        s[(i, i)] += T::from(n as f32);
    }
    s
}

/// The best of `runs` timings of `f` (each given a fresh copy of `a`), in milliseconds.
fn best<T: faer::traits::RealField>(runs: usize, a: &Mat<T>, mut f: impl FnMut(Mat<T>)) -> f64 {
    (0..runs)
        .map(|_| {
            let copy = a.clone();
            let t = Instant::now();
            f(copy);
            t.elapsed().as_secs_f64() * 1e3
        })
        .fold(f64::INFINITY, f64::min)
}

fn cholesky<T: faer::traits::RealField + Copy + From<f32>>(n: usize) -> f64 {
    let req = llt::factor::cholesky_in_place_scratch::<T>(n, Par::Seq, Default::default());
    let mut mem = MemBuffer::new(req);
    best(20, &spd::<T>(n), |mut a| {
        llt::factor::cholesky_in_place(
            a.as_mut(),
            Default::default(),
            Par::Seq,
            MemStack::new(&mut mem),
            Default::default(),
        )
        .expect("positive definite");
        std::hint::black_box(a);
    })
}

fn main() {
    faer::set_global_parallelism(Par::Seq);
    println!("| unknowns | Cholesky, single | Cholesky, double | LU, single | product, single |");
    println!("|---:|---:|---:|---:|---:|");
    for n in [300, 600, 966] {
        let a = spd::<f32>(n);
        let lu = best(20, &a, |a| {
            std::hint::black_box(a.as_ref().partial_piv_lu());
        });
        let x = Mat::<f32>::from_fn(n, 1, |i, _| i as f32);
        let product = best(20, &a, |a| {
            std::hint::black_box(&a * &x);
        });
        println!(
            "| {n} | {:.2} | {:.2} | {lu:.2} | {product:.3} |",
            cholesky::<f32>(n),
            cholesky::<f64>(n),
        );
    }
}
