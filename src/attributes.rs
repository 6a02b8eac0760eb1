//! Every configuration attribute of the sensor, described once: its name, meaning, unit,
//! default and what is accepted.
//!
//! This table is the one home of each attribute. The configuration's parser
//! ([`crate::config`]) reads its defaults and checks each number against its range; the gel's
//! parameters ([`crate::mpm::GelParams::default`]) take the physical defaults from it;
//! MuJoCo's attribute list ([`NAMES`]), the Python package (`tacrom.attribute_table()`,
//! through [`table_json`]) and the README's attribute table (written by
//! `tacrom doc-tables --write`, checked by a test) are generated from it. This module
//! depends on nothing else in the crate.

/// One configuration attribute.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Attribute {
    /// The name used in MJCF (`<config key="..."/>`).
    pub name: &'static str,
    /// What it sets, in one sentence.
    pub meaning: &'static str,
    /// SI unit of its numbers (empty for none).
    pub unit: &'static str,
    /// Its default.
    pub default: Default,
    /// What is accepted.
    pub valid: Valid,
}

/// An attribute's default.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Default {
    /// One number.
    Number(f64),
    /// Several numbers, space-separated in MJCF.
    Numbers(&'static [f64]),
    /// Several integers, space-separated in MJCF.
    Integers(&'static [usize]),
    /// One word (or words) as written in MJCF.
    Text(&'static str),
    /// A default that depends on other attributes, in words.
    Depends(&'static str),
}

/// What an attribute accepts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Valid {
    /// Each of its numbers within a range.
    Range(Range),
    /// Each of its integers within `lo..=hi`.
    Integers {
        /// Smallest accepted.
        lo: usize,
        /// Largest accepted.
        hi: usize,
    },
    /// One of these words (or, with `several`, any of them, each once).
    Words {
        /// The accepted words.
        words: &'static [&'static str],
        /// Whether several may be listed.
        several: bool,
    },
    /// Described in words (checks that need other attributes, files or the scene).
    Described(&'static str),
}

/// A closed interval `[lo, hi]`, or `(lo, hi]` when `lo_open`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Range {
    /// Lower bound.
    pub lo: f64,
    /// Upper bound (included).
    pub hi: f64,
    /// Whether `lo` itself is excluded.
    pub lo_open: bool,
}

impl Range {
    /// `[lo, hi]`.
    pub const fn closed(lo: f64, hi: f64) -> Self {
        Self {
            lo,
            hi,
            lo_open: false,
        }
    }

    /// `(lo, hi]`.
    pub const fn open_below(lo: f64, hi: f64) -> Self {
        Self {
            lo,
            hi,
            lo_open: true,
        }
    }

    /// Whether `x` lies in the range (never for NaN).
    pub fn contains(&self, x: f64) -> bool {
        (if self.lo_open {
            x > self.lo
        } else {
            x >= self.lo
        }) && x <= self.hi
    }
}

impl std::fmt::Display for Range {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let open = if self.lo_open { '(' } else { '[' };
        write!(f, "{open}{}, {}]", number(self.lo), number(self.hi))
    }
}

/// `x` as a reader writes it: `1e10`, `1.19e5`, `1e-6` for large and small magnitudes,
/// `0.43` and `1050` otherwise.
pub fn number(x: f64) -> String {
    if x != 0.0 && (x.abs() >= 1e4 || x.abs() < 1e-3) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

impl Default {
    /// The number of a [`Default::Number`] (evaluated at compile time for the constants
    /// of [`defaults`]).
    pub const fn number(&self) -> f64 {
        match self {
            Default::Number(x) => *x,
            _ => panic!("not a numeric default"),
        }
    }

    /// The first `N` numbers of a [`Default::Numbers`].
    pub const fn numbers<const N: usize>(&self) -> [f64; N] {
        match self {
            Default::Numbers(v) => {
                let mut out = [0.0; N];
                let mut i = 0;
                while i < N {
                    out[i] = v[i];
                    i += 1;
                }
                out
            }
            _ => panic!("not a list of numbers"),
        }
    }

    /// The first `N` integers of a [`Default::Integers`].
    pub const fn integers<const N: usize>(&self) -> [usize; N] {
        match self {
            Default::Integers(v) => {
                let mut out = [0; N];
                let mut i = 0;
                while i < N {
                    out[i] = v[i];
                    i += 1;
                }
                out
            }
            _ => panic!("not a list of integers"),
        }
    }

    /// The words of a [`Default::Text`].
    pub const fn text(&self) -> &'static str {
        match self {
            Default::Text(t) => t,
            _ => panic!("not a text default"),
        }
    }

    /// The default as written in MJCF, or in words where it depends on other attributes.
    pub fn to_text(&self) -> String {
        let join = |v: Vec<String>| v.join(" ");
        match self {
            Default::Number(x) => number(*x),
            Default::Numbers(v) => join(v.iter().map(|&x| number(x)).collect()),
            Default::Integers(v) => join(v.iter().map(|n| n.to_string()).collect()),
            Default::Text(t) | Default::Depends(t) => (*t).to_owned(),
        }
    }
}

impl Valid {
    /// What is accepted, in words.
    pub fn to_text(&self) -> String {
        match self {
            Valid::Range(r) => r.to_string(),
            Valid::Integers { lo, hi } => format!("integers {lo}..{hi}"),
            Valid::Words { words, several } => {
                let list = words
                    .iter()
                    .map(|w| format!("`{w}`"))
                    .collect::<Vec<_>>()
                    .join(", ");
                if *several {
                    format!("any of {list}, each once")
                } else {
                    list
                }
            }
            Valid::Described(t) => (*t).to_owned(),
        }
    }

    /// The bounds `(lo, hi)` of a [`Valid::Integers`].
    pub const fn integers(&self) -> (usize, usize) {
        match self {
            Valid::Integers { lo, hi } => (*lo, *hi),
            _ => panic!("not an integer range"),
        }
    }

    /// The numeric range, for attributes checked against one.
    pub const fn range(&self) -> Range {
        match self {
            Valid::Range(r) => *r,
            _ => panic!("not a range"),
        }
    }
}

/// `sensor`.
pub const SENSOR: Attribute = Attribute {
    name: "sensor",
    meaning: "a whole sensor from one file (written by `tacrom calibrate --gel`): its \
              attributes become this sensor's defaults, and those given beside it override \
              them",
    unit: "",
    default: Default::Depends("none: the defaults of this table"),
    valid: Valid::Described(
        "a sensor file or a folder holding `sensor.json` (relative to the working \
         directory; paths inside it relative to the file), or a shipped sensor's name: \
         `gelsight-mini`",
    ),
};

/// `physics`.
pub const PHYSICS: Attribute = Attribute {
    name: "physics",
    meaning: "which model of the gel computes the surface",
    unit: "",
    default: Default::Text("rom"),
    valid: Valid::Words {
        words: &["rigid", "coarse", "fine", "rom"],
        several: false,
    },
};

/// `outputs`.
pub const OUTPUTS: Attribute = Attribute {
    name: "outputs",
    meaning: "the outputs, in sensordata order (see the output table)",
    unit: "",
    default: Default::Text("depth"),
    valid: Valid::Words {
        words: &[
            "depth", "force", "contact", "rgb", "pressure", "shear", "markers",
        ],
        several: true,
    },
};

/// `resolution`.
pub const RESOLUTION: Attribute = Attribute {
    name: "resolution",
    meaning: "image width and height",
    unit: "px",
    default: Default::Integers(&[320, 240]),
    valid: Valid::Integers { lo: 1, hi: 4096 },
};

/// `fov`.
pub const FOV: Attribute = Attribute {
    name: "fov",
    meaning: "extent of the image on the gel, x and y (one number: a square)",
    unit: "m",
    default: Default::Numbers(&[0.024, 0.018]),
    valid: Valid::Described("positive, within `size`"),
};

/// `size`.
pub const SIZE: Attribute = Attribute {
    name: "size",
    meaning: "gel extent Lx, Ly and thickness T",
    unit: "m",
    default: Default::Numbers(&[0.03, 0.03, 0.004]),
    valid: Valid::Range(Range::open_below(0.0, 1.0)),
};

/// `indenters`.
pub const INDENTERS: Attribute = Attribute {
    name: "indenters",
    meaning: "names of the bodies whose geoms may press the gel",
    unit: "",
    default: Default::Depends("every body not welded to the sensor's"),
    valid: Valid::Described("names of bodies of the model"),
};

/// `young`.
pub const YOUNG: Attribute = Attribute {
    name: "young",
    meaning: "Young's modulus of the gel",
    unit: "Pa",
    default: Default::Number(1.19e5),
    valid: Valid::Range(Range::closed(1e2, 1e10)),
};

/// `poisson`.
pub const POISSON: Attribute = Attribute {
    name: "poisson",
    meaning: "Poisson's ratio of the gel",
    unit: "",
    default: Default::Number(0.43),
    valid: Valid::Range(Range::closed(0.0, 0.4999)),
};

/// `density`.
pub const DENSITY: Attribute = Attribute {
    name: "density",
    meaning: "density of the gel",
    unit: "kg/m^3",
    default: Default::Number(1050.0),
    valid: Valid::Range(Range::closed(1.0, 1e5)),
};

/// `friction`.
pub const FRICTION: Attribute = Attribute {
    name: "friction",
    meaning: "Coulomb friction coefficient between the gel and the indenters",
    unit: "",
    default: Default::Number(0.5),
    valid: Valid::Range(Range::closed(0.0, 10.0)),
};

/// `dx`.
pub const DX: Attribute = Attribute {
    name: "dx",
    meaning: "MPM grid spacing of the gel (coarse, fine, rom)",
    unit: "m",
    default: Default::Depends(
        "coarse 0.35 T (1.4e-3 on the default 4 mm gel), at most 1.4e-3; rom 0.35 T; fine 3e-4, \
         at most T/4",
    ),
    valid: Valid::Described("(0, T/2], at most 2e7 grid cells"),
};

/// `threads`.
pub const THREADS: Attribute = Attribute {
    name: "threads",
    meaning: "worker threads of this sensor's solver (results are the same for any count)",
    unit: "",
    default: Default::Integers(&[1]),
    valid: Valid::Integers { lo: 1, hi: 256 },
};

/// `model`.
pub const MODEL: Attribute = Attribute {
    name: "model",
    meaning: "directory of the reduced-order model (`rom`)",
    unit: "",
    default: Default::Depends(
        "the shipped `rom-linear-narrow` on gels of 3.5 mm and more, `rom-linear` on \
         thinner ones, on the linear solver (`rom-default`, the relaxation's, with \
         `solver=\"relaxation\"`)",
    ),
    valid: Valid::Described(
        "a directory with a `manifest.json` that serves this gel, or a shipped model's \
         name: `rom-linear-narrow`, `rom-linear` (its encoder, the paper's decoder widths), \
         `rom-family` (trained over the gel family; in the \
         checkout), `rom-default` (the relaxation's, with the linear \
         solver for contacts it misses: `physics=\"rom\"` as it was before the linear gel)",
    ),
};

/// `refine`.
pub const REFINE: Attribute = Attribute {
    name: "refine",
    meaning: "latent refinement of `rom` (L-BFGS on the reduced energy)",
    unit: "",
    default: Default::Depends(
        "as the model's manifest says (off in every shipped model: it measured no gain)",
    ),
    valid: Valid::Words {
        words: &["true", "false"],
        several: false,
    },
};

/// `tolerance`.
pub const TOLERANCE: Attribute = Attribute {
    name: "tolerance",
    meaning: "convergence threshold of the gel's solve: the largest out-of-balance nodal \
              force over the load",
    unit: "",
    default: Default::Depends("coarse and rom 3e-3, fine 1e-3"),
    valid: Valid::Range(Range::closed(1e-6, 0.5)),
};

/// `material`.
pub const MATERIAL: Attribute = Attribute {
    name: "material",
    meaning: "the gel's constitutive model (both share the same small-strain response)",
    unit: "",
    default: Default::Text("corotated"),
    valid: Valid::Words {
        words: crate::mpm::Material::NAMES,
        several: false,
    },
};

/// `markers`.
pub const MARKERS: Attribute = Attribute {
    name: "markers",
    meaning: "markers printed on the gel along x and y, spread evenly over `fov` (the \
              `markers` output)",
    unit: "",
    default: Default::Integers(&[9, 7]),
    valid: Valid::Integers { lo: 1, hi: 256 },
};

/// `optics`.
pub const OPTICS: Attribute = Attribute {
    name: "optics",
    meaning: "calibrated optics of the `rgb` output (a file written by `tacrom calibrate`); \
              read only when `rgb` is listed",
    unit: "",
    default: Default::Depends("the built-in three-light shading"),
    valid: Valid::Described("a readable optics file, relative to the working directory"),
};

/// `camera`.
pub const CAMERA: Attribute = Attribute {
    name: "camera",
    meaning: "the camera under the gel: vertical rays, or a pinhole on the gel's axis `D` \
              below its bottom face looking up through it",
    unit: "m",
    default: Default::Text("orthographic"),
    valid: Valid::Described("`orthographic`, or `pinhole D` with D in (0, 1]"),
};

/// The largest pinhole distance `D` accepted (m): `pinhole 20` is a camera 20 m away, far
/// more likely millimetres written as metres.
pub const CAMERA_DISTANCE: Range = Range::open_below(0.0, 1.0);

/// `index`.
pub const INDEX: Attribute = Attribute {
    name: "index",
    meaning: "the gel's refractive index over the camera medium's (a pinhole camera's rays \
              bend at the gel's bottom face)",
    unit: "",
    default: Default::Number(1.0),
    valid: Valid::Range(Range::closed(1.0, 3.0)),
};

/// `view`.
pub const VIEW: Attribute = Attribute {
    name: "view",
    meaning: "the side the images are seen from: the indenter's, or the camera's under the \
              gel (columns mirrored, as a real sensor's camera records them)",
    unit: "",
    default: Default::Text("indenter"),
    valid: Valid::Words {
        words: &["indenter", "camera"],
        several: false,
    },
};

/// `coupling`.
pub const COUPLING: Attribute = Attribute {
    name: "coupling",
    meaning: "the gel pushes back: its contact wrench is applied to the bodies pressing it \
              and the opposite to the sensor's body (needs a gel physics)",
    unit: "",
    default: Default::Text("off"),
    valid: Valid::Words {
        words: &["on", "off"],
        several: false,
    },
};

/// `damping`.
pub const DAMPING: Attribute = Attribute {
    name: "damping",
    meaning: "the gel's retardation time in the coupling (Kelvin-Voigt: `F + damping dF/dt`)",
    unit: "s",
    default: Default::Number(0.01),
    valid: Valid::Range(Range::closed(0.0, 1.0)),
};

/// `gel_geom`.
pub const GEL_GEOM: Attribute = Attribute {
    name: "gel_geom",
    meaning: "with `coupling=\"on\"`: the geom of the sensor's body that stands for the gel \
              in MuJoCo's collision (its face on the gel's surface); its contacts with the \
              indenters carry the gel's push-back, taken implicitly in MuJoCo's constraint \
              solve",
    unit: "",
    default: Default::Depends("none: the push-back is an explicit force"),
    valid: Valid::Described("the name of a geom welded to the sensor's body"),
};

/// `hold`.
pub const HOLD: Attribute = Attribute {
    name: "hold",
    meaning: "the motion below which a frame is the last solved one again: where every \
              indenter touching the gel moved less than this (at any point of the gel it \
              can reach; at a contact shallower than 0.5 mm, that fraction of it) since the \
              last solve, the outputs are that solve's, and nothing is solved; 0 solves \
              every frame (as does the explicit coupling, without `gel_geom`); larger \
              values trade accuracy for speed (docs/rl.md, \"A looser hold\")",
    unit: "m",
    default: Default::Number(1e-6),
    valid: Valid::Range(Range::closed(0.0, 1e-4)),
};

/// `solver`.
pub const SOLVER: Attribute = Attribute {
    name: "solver",
    meaning: "the gel's equilibrium solver",
    unit: "",
    default: Default::Depends(
        "chosen from the gel (`newton` from Poisson 0.49, `relaxation` below it with \
         `linear` for contacts it misses; `rom` with its shipped models: `linear`, with a \
         model of your own: as for `coarse`, name the one its recipe needs)",
    ),
    valid: Valid::Words {
        words: &["relaxation", "newton", "total", "linear"],
        several: false,
    },
};

/// Every attribute the plugin declares to MuJoCo, in table order.
pub const TABLE: &[Attribute] = &[
    SENSOR, PHYSICS, OUTPUTS, RESOLUTION, FOV, SIZE, INDENTERS, YOUNG, POISSON, DENSITY, FRICTION,
    DX, THREADS, MODEL, REFINE, TOLERANCE, MATERIAL, MARKERS, OPTICS, CAMERA, VIEW, INDEX,
    COUPLING, DAMPING, GEL_GEOM, HOLD, SOLVER,
];

/// The attributes' names, in table order (what MuJoCo is told).
pub const NAMES: [&str; TABLE.len()] = {
    let mut names = [""; TABLE.len()];
    let mut i = 0;
    while i < TABLE.len() {
        names[i] = TABLE[i].name;
        i += 1;
    }
    names
};

/// The attribute called `name`.
pub fn named(name: &str) -> Option<&'static Attribute> {
    TABLE.iter().find(|a| a.name == name)
}

/// The defaults as values (a GelSight Mini-like gel, the paper's material).
pub mod defaults {
    /// Physics mode.
    pub const PHYSICS: &str = super::PHYSICS.default.text();
    /// Outputs.
    pub const OUTPUTS: &str = super::OUTPUTS.default.text();
    /// Image width and height (pixels).
    pub const RESOLUTION: [usize; 2] = super::RESOLUTION.default.integers();
    /// Image extent (m).
    pub const FOV: [f64; 2] = super::FOV.default.numbers();
    /// Gel extent Lx, Ly, T (m).
    pub const SIZE: [f64; 3] = super::SIZE.default.numbers();
    /// Young's modulus (Pa).
    pub const YOUNG: f64 = super::YOUNG.default.number();
    /// Poisson's ratio.
    pub const POISSON: f64 = super::POISSON.default.number();
    /// Density (kg/m^3).
    pub const DENSITY: f64 = super::DENSITY.default.number();
    /// Friction coefficient.
    pub const FRICTION: f64 = super::FRICTION.default.number();
    /// Threads.
    pub const THREADS: usize = super::THREADS.default.integers::<1>()[0];
    /// Markers along x and y: a 9 x 7 grid over the 24 x 18 mm image, about 2.6 mm apart
    /// (GelSight Mini-like).
    pub const MARKERS: [usize; 2] = super::MARKERS.default.integers();
    /// Refractive index ratio: none.
    pub const INDEX: f64 = super::INDEX.default.number();
    /// Retardation time of the coupling (s): near critical damping for a 20 g object on
    /// the default gel (stiffness about 600 N/m at 0.4 mm, so `2 / omega` is 12 ms), and
    /// well inside the stable range `damping k dt / m < 2` at MuJoCo's 2 ms step.
    pub const DAMPING: f64 = super::DAMPING.default.number();
    /// `hold` (m).
    pub const HOLD: f64 = super::HOLD.default.number();
    /// The coarse grid's spacing (m): about 1e4 particles in the default gel.
    pub const COARSE_DX: f64 = 1.4e-3;
    /// The coarse grid's spacing in gel thicknesses: the default gel's 1.4 mm over its
    /// 4 mm (2.86 cells through the layer), kept at every thickness
    /// ([`crate::config::Physics::default_dx`]).
    pub const COARSE_LAYER: f64 = 0.35;
    /// The fine grid's spacing (m): 100 x 100 x ~13 cells, about 1e6 particles in the
    /// default gel.
    pub const FINE_DX: f64 = 0.3e-3;
}

/// The attribute table as JSON, for the Python package: a list of objects with `name`,
/// `meaning`, `unit`, `default` (as written in MJCF, or in words) and `valid` (in words).
pub fn table_json() -> String {
    let rows: Vec<String> = TABLE
        .iter()
        .map(|a| {
            format!(
                "{{\"name\":{},\"meaning\":{},\"unit\":{},\"default\":{},\"valid\":{}}}",
                json_string(a.name),
                json_string(a.meaning),
                json_string(a.unit),
                json_string(&a.default.to_text()),
                json_string(&a.valid.to_text())
            )
        })
        .collect();
    format!("[{}]", rows.join(","))
}

fn json_string(s: &str) -> String {
    serde_json::to_string(s).unwrap_or_else(|_| "\"\"".into())
}

/// The README's attribute table (Markdown), between its `tacrom:attributes` markers.
pub fn markdown_table() -> String {
    let mut out =
        String::from("| attribute | meaning | unit | default | valid |\n|---|---|---|---|---|\n");
    for a in TABLE {
        let default = match a.default {
            Default::Depends(t) => t.to_owned(),
            d => format!("`{}`", d.to_text()),
        };
        out.push_str(&format!(
            "| `{}` | {} | {} | {} | {} |\n",
            a.name,
            a.meaning,
            a.unit,
            default,
            a.valid.to_text()
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_unique_and_defaults_lie_in_their_ranges() {
        for (i, a) in TABLE.iter().enumerate() {
            assert!(
                TABLE[..i].iter().all(|b| b.name != a.name),
                "{} twice",
                a.name
            );
            let numbers: Vec<f64> = match a.default {
                Default::Number(x) => vec![x],
                Default::Numbers(v) => v.to_vec(),
                Default::Integers(v) => v.iter().map(|&n| n as f64).collect(),
                _ => vec![],
            };
            match a.valid {
                Valid::Range(r) => {
                    for x in &numbers {
                        assert!(r.contains(*x), "{}: default {x} outside {r}", a.name);
                    }
                }
                Valid::Integers { lo, hi } => {
                    for x in &numbers {
                        assert!((lo as f64..=hi as f64).contains(x), "{}", a.name);
                    }
                }
                Valid::Words { words, .. } => {
                    if let Default::Text(t) = a.default {
                        for w in t.split_whitespace() {
                            assert!(words.contains(&w), "{}: default {w}", a.name);
                        }
                    }
                }
                Valid::Described(_) => {}
            }
        }
    }

    #[test]
    fn numbers_are_written_as_a_reader_would() {
        assert_eq!(number(1e10), "1e10");
        assert_eq!(number(1.19e5), "1.19e5");
        assert_eq!(number(1e-6), "1e-6");
        assert_eq!(number(0.4999), "0.4999");
        assert_eq!(number(1050.0), "1050");
        assert_eq!(number(0.0), "0");
        assert_eq!(YOUNG.valid.to_text(), "[100, 1e10]");
        assert_eq!(SIZE.valid.to_text(), "(0, 1]");
    }

    #[test]
    fn the_json_table_parses_and_names_every_attribute() {
        let v: serde_json::Value = serde_json::from_str(&table_json()).unwrap();
        let names: Vec<&str> = v
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r["name"].as_str().unwrap())
            .collect();
        assert_eq!(names, NAMES);
        let young = names.iter().position(|&n| n == YOUNG.name).unwrap();
        assert_eq!(v[young]["default"], "1.19e5");
    }
}
