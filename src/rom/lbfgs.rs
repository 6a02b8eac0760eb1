//! Limited-memory BFGS (Nocedal and Wright, Algorithm 7.4) with a backtracking Armijo line
//! search, for the latent refinement: a few dozen unknowns, at most ten iterations.

/// Settings of [`minimize`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LbfgsOptions {
    /// Most iterations (accepted steps).
    pub max_iterations: usize,
    /// Stop when the largest gradient component is below this.
    pub tolerance: f64,
    /// Curvature pairs kept.
    pub memory: usize,
    /// Most energy evaluations per line search.
    pub max_line_search: usize,
}

impl Default for LbfgsOptions {
    fn default() -> Self {
        Self {
            max_iterations: 10,
            tolerance: 1e-5,
            memory: 6,
            max_line_search: 8,
        }
    }
}

/// What [`minimize`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LbfgsReport {
    /// Accepted steps.
    pub iterations: usize,
    /// Energy evaluations (each with its gradient).
    pub evaluations: usize,
    /// Energy at the start.
    pub initial: f64,
    /// Energy at the end.
    pub last: f64,
    /// Largest gradient component at the end.
    pub gradient: f64,
    /// Whether the gradient tolerance was met.
    pub converged: bool,
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn amax(a: &[f64]) -> f64 {
    a.iter().fold(0.0, |m, v| m.max(v.abs()))
}

/// Minimises `f` from `x` (updated in place). `f(x, grad)` returns the energy and writes
/// its gradient; an `Err` stops the minimisation and is returned.
pub fn minimize<E>(
    x: &mut [f64],
    options: &LbfgsOptions,
    mut f: impl FnMut(&[f64], &mut [f64]) -> Result<f64, E>,
) -> Result<LbfgsReport, E> {
    let n = x.len();
    let mut g = vec![0.0; n];
    let mut fx = f(x, &mut g)?;
    let mut report = LbfgsReport {
        evaluations: 1,
        initial: fx,
        last: fx,
        gradient: amax(&g),
        ..Default::default()
    };
    let (mut s_hist, mut y_hist): (Vec<Vec<f64>>, Vec<Vec<f64>>) = (Vec::new(), Vec::new());
    let mut d = vec![0.0; n];
    let mut x_new = vec![0.0; n];
    let mut g_new = vec![0.0; n];
    let mut alpha = vec![0.0; options.memory];
    while report.iterations < options.max_iterations {
        if !fx.is_finite() || amax(&g) < options.tolerance {
            break;
        }
        // Two-loop recursion: d = -H g.
        d.copy_from_slice(&g);
        for k in (0..s_hist.len()).rev() {
            let rho = 1.0 / dot(&y_hist[k], &s_hist[k]);
            alpha[k] = rho * dot(&s_hist[k], &d);
            for (di, yi) in d.iter_mut().zip(&y_hist[k]) {
                *di -= alpha[k] * yi;
            }
        }
        let gamma = match (s_hist.last(), y_hist.last()) {
            (Some(s), Some(y)) => dot(s, y) / dot(y, y),
            // First step: a unit step of the largest component, at most.
            _ => 1.0 / amax(&g).max(1.0),
        };
        d.iter_mut().for_each(|v| *v *= gamma);
        for k in 0..s_hist.len() {
            let rho = 1.0 / dot(&y_hist[k], &s_hist[k]);
            let beta = rho * dot(&y_hist[k], &d);
            for (di, si) in d.iter_mut().zip(&s_hist[k]) {
                *di += (alpha[k] - beta) * si;
            }
        }
        d.iter_mut().for_each(|v| *v = -*v);
        let mut slope = dot(&g, &d);
        if !(slope < 0.0) {
            // Not a descent direction: fall back to steepest descent.
            s_hist.clear();
            y_hist.clear();
            d.iter_mut()
                .zip(&g)
                .for_each(|(di, gi)| *di = -gi / amax(&g).max(1.0));
            slope = dot(&g, &d);
        }
        let mut step = 1.0;
        let mut accepted = false;
        for _ in 0..options.max_line_search {
            for i in 0..n {
                x_new[i] = x[i] + step * d[i];
            }
            let f_new = f(&x_new, &mut g_new)?;
            report.evaluations += 1;
            if f_new.is_finite() && f_new <= fx + 1e-4 * step * slope {
                let s: Vec<f64> = (0..n).map(|i| x_new[i] - x[i]).collect();
                let y: Vec<f64> = (0..n).map(|i| g_new[i] - g[i]).collect();
                if dot(&s, &y) > 1e-12 * dot(&y, &y).max(1e-300) {
                    if s_hist.len() == options.memory {
                        s_hist.remove(0);
                        y_hist.remove(0);
                    }
                    s_hist.push(s);
                    y_hist.push(y);
                }
                x.copy_from_slice(&x_new);
                g.copy_from_slice(&g_new);
                fx = f_new;
                accepted = true;
                break;
            }
            step *= 0.5;
        }
        if !accepted {
            break;
        }
        report.iterations += 1;
    }
    report.last = fx;
    report.gradient = amax(&g);
    report.converged = report.gradient < options.tolerance;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minimises_a_quadratic_within_ten_iterations() {
        // f = sum_i c_i (x_i - i)^2 / 2, condition number 10.
        let c: Vec<f64> = (0..8).map(|i| 1.0 + i as f64 * 9.0 / 7.0).collect();
        let mut x = vec![0.0; 8];
        let r = minimize::<()>(
            &mut x,
            &LbfgsOptions {
                max_iterations: 30,
                ..Default::default()
            },
            |x, g| {
                let mut f = 0.0;
                for i in 0..8 {
                    let d = x[i] - i as f64;
                    f += 0.5 * c[i] * d * d;
                    g[i] = c[i] * d;
                }
                Ok(f)
            },
        )
        .unwrap();
        assert!(r.converged, "{r:?}");
        assert!(r.last < 1e-9 && r.last < r.initial);
    }
}
