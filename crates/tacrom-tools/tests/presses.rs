//! The presses of `tacrom gen-data` are a function of the seed alone: a data set regenerated
//! with the same seed holds the same presses. The values below were computed by the
//! generator the first data sets were made with (a hand-written SplitMix64); a change of
//! random generator, of the order of the draws or of their arithmetic shows up here.

use tacrom_tools::datagen::{draw_press, MeshLibrary, Rng};

const SIZE: [f64; 3] = [0.03, 0.03, 0.004];

#[test]
fn the_random_stream_of_a_sample_is_unchanged() {
    let mut r = Rng::new(1, 0);
    assert_eq!(
        [r.next_u64(), r.next_u64(), r.next_u64()],
        [
            13757245211066428519,
            17911839290282890590,
            8196980753821780235
        ]
    );
    let mut r = Rng::new(7, 3);
    assert_eq!(r.uniform(-2.0, 3.0), 1.2229565187678553);
    assert_eq!(r.below(7), 6);
}

#[test]
fn seed_1_draws_the_presses_it_always_drew() {
    // (family, poses, first pose's translation (m), its rotation quaternion [i, j, k, w]).
    let expected: [(&str, usize, [f64; 3], [f64; 4]); 6] = [
        (
            "ridges",
            1,
            [
                5.414219550286015e-4,
                -9.605190026291243e-4,
                1.3640049073742353e-4,
            ],
            [
                -2.6077670567604343e-2,
                1.8120577358717135e-2,
                9.545154882296565e-1,
                2.964654828199309e-1,
            ],
        ),
        (
            "bumps",
            2,
            [
                -5.267214336069651e-3,
                1.5289758819369513e-3,
                -9.188732096532517e-4,
            ],
            [
                -1.2153723584244999e-3,
                7.917236785569834e-4,
                4.787501082572846e-1,
                8.779500155972922e-1,
            ],
        ),
        (
            "heightfield",
            1,
            [
                -5.217753423637887e-3,
                7.028608764610723e-3,
                1.2909322291520071e-3,
            ],
            [
                -6.569555683741055e-2,
                3.825997551634916e-4,
                4.736804829486366e-1,
                -8.782429888719843e-1,
            ],
        ),
        (
            "box",
            1,
            [
                9.013882119362349e-4,
                7.471101331329635e-3,
                3.0097143118840504e-3,
            ],
            [
                -1.5389795591176465e-3,
                1.6414328914448006e-2,
                3.6488574256929485e-1,
                9.309063305284047e-1,
            ],
        ),
        (
            "sphere",
            1,
            [
                6.863661029491774e-4,
                -1.2364129262487228e-3,
                5.834591633562583e-3,
            ],
            [
                2.384252922971909e-3,
                1.265093208958612e-2,
                2.146697224117622e-1,
                9.766018531289611e-1,
            ],
        ),
        (
            "edge",
            1,
            [
                -7.095717636000698e-3,
                -4.29034248181611e-3,
                4.493371914169273e-3,
            ],
            [
                -6.744314596839301e-1,
                7.313149188074458e-2,
                9.494247726785755e-2,
                -7.285464412747771e-1,
            ],
        ),
    ];
    for (i, (family, poses, t, q)) in expected.into_iter().enumerate() {
        let p = draw_press(1, i as u64, &mut MeshLibrary::default(), &[], SIZE).unwrap();
        assert_eq!(p.family, family, "sample {i}");
        assert_eq!(p.poses.len(), poses, "sample {i}");
        let v = p.poses[0].translation.vector;
        assert_eq!([v.x, v.y, v.z], t, "sample {i}");
        let c = p.poses[0].rotation.coords;
        assert_eq!([c.x, c.y, c.z, c.w], q, "sample {i}");
    }
}

/// The families drawn only when named (`--families blob,stone,brick`): each is drawn when
/// named alone, none joins the default set, and each shape is a signed distance that the
/// contact and the sphere tracing can use: never steeper than 1 (a lower bound of the
/// true distance), negative somewhere inside its box and positive outside it.
#[test]
fn the_extra_families_are_drawn_only_when_named_and_are_signed_distances() {
    use nalgebra::Point3;
    for i in 0..40 {
        let p = draw_press(1, i, &mut MeshLibrary::default(), &[], SIZE).unwrap();
        assert!(
            !tacrom_tools::datagen::EXTRA_FAMILIES.contains(&p.family.as_str()),
            "sample {i}: {}",
            p.family
        );
    }
    let mut r = Rng::new(5, 0);
    for family in tacrom_tools::datagen::EXTRA_FAMILIES {
        for i in 0..12 {
            let only = [family.to_string()];
            let p = draw_press(1, i, &mut MeshLibrary::default(), &only, SIZE).unwrap();
            assert_eq!(p.family, *family);
            let b = p.shape.aabb();
            let pad = 1e-3;
            let mut point = || {
                Point3::new(
                    r.uniform(b.min.x - pad, b.max.x + pad),
                    r.uniform(b.min.y - pad, b.max.y + pad),
                    r.uniform(b.min.z - pad, b.max.z + pad),
                )
            };
            let mut inside = false;
            for _ in 0..2000 {
                let (a, c) = (point(), point());
                let (da, dc) = (p.shape.distance(&a), p.shape.distance(&c));
                assert!(
                    (da - dc).abs() <= (a - c).norm() * (1.0 + 1e-9),
                    "{family} {i}: steeper than 1"
                );
                inside |= da < 0.0;
                let outside = a.x < b.min.x
                    || a.x > b.max.x
                    || a.y < b.min.y
                    || a.y > b.max.y
                    || a.z < b.min.z
                    || a.z > b.max.z;
                if outside {
                    assert!(da > 0.0, "{family} {i}: negative outside its box");
                }
            }
            assert!(inside, "{family} {i}: no point inside");
        }
    }
}
