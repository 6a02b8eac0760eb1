//! The implicit coupling's rows moved to where the gel presses (`gel_contacts::shift_rows`),
//! in real MuJoCo: after the move, every translational row of a contact is MuJoCo's own
//! Jacobian of that row's direction at the moved point (`mj_jac` on both bodies), and its
//! torsional and rolling rows are as they were; for both cones, dense and sparse
//! Jacobians, and each contact dimension.

mod common;

use nalgebra::Vector3;
use tacrom::mujoco::{
    gel_contacts::{shift_rows, Turns},
    sys,
};

/// A block resting turned on a pad that hangs on a hinge and a slide (so that the
/// Jacobians' turning part is not the identity), pressed 0.5 mm into it.
fn scene(cone: &str, jacobian: &str, condim: usize) -> String {
    format!(
        r#"<mujoco>
  <option cone="{cone}" jacobian="{jacobian}"/>
  <worldbody>
    <body name="arm" pos="0 0 0.1" euler="4 -3 0">
      <joint name="hinge" type="hinge" axis="0 1 0"/>
      <joint name="slide" type="slide" axis="1 0 0"/>
      <geom name="pad" type="box" size="0.02 0.02 0.005" condim="{condim}" mass="0.1"/>
    </body>
    <body name="block" pos="0.003 0.004 0.1145" euler="0 0 20">
      <freejoint/>
      <geom name="block" type="box" size="0.01 0.01 0.01" condim="{condim}" mass="0.05"/>
    </body>
  </worldbody>
</mujoco>"#
    )
}

/// Row `r` of the constraint Jacobian as a dense row of `nv` numbers.
///
/// # Safety
/// `d` is valid after `mj_forward` and `r < nefc`.
unsafe fn row(m: &sys::mjModel, d: &sys::mjData, r: usize) -> Vec<f64> {
    let nv = m.nv as usize;
    let mut out = vec![0.0; nv];
    unsafe {
        if sys::mj_isSparse(m) != 0 {
            let adr = *d.efc_J_rowadr.add(r) as usize;
            let nnz = *d.efc_J_rownnz.add(r) as usize;
            for k in adr..adr + nnz {
                out[*d.efc_J_colind.add(k) as usize] = *d.efc_J.add(k);
            }
        } else {
            out.copy_from_slice(std::slice::from_raw_parts(d.efc_J.add(r * nv), nv));
        }
    }
    out
}

/// `a^T (J_p(b2, x) - J_p(b1, x))` from MuJoCo's own point Jacobians.
///
/// # Safety
/// `d` is valid after `mj_forward`; both bodies ids of `m`.
unsafe fn point_row(
    m: &sys::mjModel,
    d: &sys::mjData,
    bodies: [i32; 2],
    x: &Vector3<f64>,
    a: &Vector3<f64>,
) -> Vec<f64> {
    let nv = m.nv as usize;
    let mut jac = [vec![0.0; 3 * nv], vec![0.0; 3 * nv]];
    for (j, &b) in jac.iter_mut().zip(&bodies) {
        unsafe { sys::mj_jac(m, d, j.as_mut_ptr(), std::ptr::null_mut(), x.as_ptr(), b) };
    }
    (0..nv)
        .map(|c| {
            (0..3)
                .map(|i| a[i] * (jac[1][i * nv + c] - jac[0][i * nv + c]))
                .sum()
        })
        .collect()
}

#[test]
fn moved_rows_are_mujocos_jacobians_at_the_moved_point() {
    let shift = Vector3::new(1.3e-3, -2.1e-3, 0.4e-3);
    let mut checked = 0;
    for cone in ["elliptic", "pyramidal"] {
        for jacobian in ["dense", "sparse"] {
            for condim in [1, 3, 4, 6] {
                let case = format!("{cone} {jacobian} condim {condim}");
                let model = common::load_xml(&scene(cone, jacobian, condim)).expect("loads");
                let mut data = model.make_data();
                data.set_qpos(0, 0.05);
                data.forward(&model);
                let m = model.raw();
                // SAFETY: valid model and data after mj_forward; rows and contacts within
                // MuJoCo's counts.
                unsafe {
                    let d = &mut *data.0;
                    let nefc = d.nefc as usize;
                    let ncon = d.ncon as usize;
                    assert!(ncon > 0, "{case}: no contact");
                    let before: Vec<Vec<f64>> = (0..nefc).map(|r| row(m, d, r)).collect();
                    let elliptic = cone == "elliptic";
                    // One for the data's contacts, all between the same two bodies.
                    let mut turns = Turns::default();
                    for i in 0..ncon {
                        let con = *d.contact.add(i);
                        let efc = con.efc_address as usize;
                        shift_rows(m, d, &con, efc, elliptic, &shift, &mut turns);
                        let bodies = [
                            *m.geom_bodyid.add(con.geom[0] as usize),
                            *m.geom_bodyid.add(con.geom[1] as usize),
                        ];
                        let x = Vector3::from(con.pos);
                        let axis =
                            |j: usize| Vector3::from_column_slice(&con.frame[3 * j..3 * j + 3]);
                        // Each row, its translational direction (None: an angular row).
                        let mut rows: Vec<(usize, Option<Vector3<f64>>)> = Vec::new();
                        if elliptic || condim == 1 {
                            for j in 0..condim {
                                rows.push((efc + j, (j < 3).then(|| axis(j))));
                            }
                        } else {
                            for k in 1..condim {
                                let t = if k <= 2 {
                                    axis(k) * con.friction[k - 1]
                                } else {
                                    Vector3::zeros()
                                };
                                rows.push((efc + 2 * (k - 1), Some(axis(0) + t)));
                                rows.push((efc + 2 * (k - 1) + 1, Some(axis(0) - t)));
                            }
                        }
                        for (r, a) in rows {
                            let now = row(m, d, r);
                            let want = match a {
                                // MuJoCo's row, moved: its change is the change of the
                                // point Jacobians along the row's direction.
                                Some(a) => {
                                    let here = point_row(m, d, bodies, &x, &a);
                                    if condim <= 3 {
                                        // A row without a turning part is the point
                                        // Jacobian along its direction before the move
                                        // too: the test's directions are MuJoCo's.
                                        let err = before[r]
                                            .iter()
                                            .zip(&here)
                                            .map(|(a, b)| (a - b).abs())
                                            .fold(0.0, f64::max);
                                        assert!(err < 1e-12, "{case}: row {r} is not MuJoCo's");
                                    }
                                    let there = point_row(m, d, bodies, &(x + shift), &a);
                                    let (b, h, t) = (&before[r], &here, &there);
                                    (0..b.len()).map(|c| b[c] - h[c] + t[c]).collect()
                                }
                                None => before[r].clone(),
                            };
                            let scale = want.iter().fold(1.0f64, |s, v| s.max(v.abs()));
                            let err = now
                                .iter()
                                .zip(&want)
                                .map(|(a, b)| (a - b).abs())
                                .fold(0.0, f64::max);
                            assert!(err <= 1e-12 * scale, "{case}: row {r}: {now:?} vs {want:?}");
                            if a.is_some() {
                                let moved = now
                                    .iter()
                                    .zip(&before[r])
                                    .map(|(a, b)| (a - b).abs())
                                    .fold(0.0, f64::max);
                                assert!(moved > 1e-6, "{case}: row {r} did not move");
                            }
                            checked += 1;
                        }
                    }
                }
            }
        }
    }
    assert!(checked > 100, "{checked} rows checked");
}
