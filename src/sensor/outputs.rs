//! The output table: every output the sensor can produce, declared once.
//!
//! An entry gives the output's name (the value in the `outputs` attribute), its shape for
//! a configuration, its unit, whether it needs a gel model, what it reads of an
//! evaluation, how it follows a pinhole camera, and its writer. `nsensordata`, the layout the plugin exports to Python and
//! the sensor's evaluation all read this table. Adding an output is one entry here and one
//! writer.

use nalgebra::Vector3;

use crate::geometry::PixelGrid;
use crate::render::markers::Markers;
use crate::render::refraction::Sampling;
use crate::render::rgb;

/// How an output's values are arranged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shape {
    /// An image of the configured resolution, `channels` values per pixel, row-major
    /// `(H, W)` for one channel, `(H, W, C)` otherwise.
    Image {
        /// Values per pixel.
        channels: usize,
    },
    /// A fixed number of values.
    Vector(usize),
    /// A row of `n` values per marker of the `markers` grid: `(NX * NY, n)`.
    PerMarker(usize),
}

/// How an output follows a pinhole camera (`camera="pinhole D"`), whose pixels see the
/// surface point their refracted ray meets rather than the one straight above their
/// centre.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Seen {
    /// Written as it is: not an image (force), or the image the refraction pass itself
    /// computes (depth).
    AsWritten,
    /// An image of the surface on the orthographic pixel grid, resampled at the point each
    /// pixel sees with the given sampling.
    Resampled(Sampling),
    /// Defined for the orthographic camera only: refused at load with a pinhole camera.
    Refused,
}

/// A physical image a model computes on the image grid after its solve, beside the depth.
/// Each is one buffer of the sensor, sized when an output needs it, and copied, reset and
/// cleared for the frame without contact by one rule; a model computes it in
/// [`super::models::SurfaceModel::field`]. A new one is a variant here (its channels), an
/// arm there, and the output that writes it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Field {
    /// The normal contact pressure of the gel on the indenters (Pa).
    Pressure,
    /// The in-plane displacement of the gel surface seen at each pixel, x then y (m).
    Shear,
}

impl Field {
    /// Every field, in the order the sensor computes them.
    pub const ALL: [Field; 2] = [Field::Pressure, Field::Shear];

    /// Values per pixel.
    pub const fn channels(self) -> usize {
        match self {
            Field::Pressure => 1,
            Field::Shear => 2,
        }
    }

    /// Its place in [`Field::ALL`] and in the arrays indexed by field.
    pub const fn index(self) -> usize {
        self as usize
    }
}

/// What an evaluation must compute for an output.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Needs {
    /// The depth image.
    pub depth: bool,
    /// The gel's contact force.
    pub force: bool,
    /// The markers' displacements.
    pub markers: bool,
    /// The physical images, one bit per [`Field`] at its [`Field::index`].
    fields: u8,
}

impl Needs {
    /// The field `f` alone.
    pub const fn field(f: Field) -> Needs {
        Needs {
            fields: 1 << f.index(),
            ..Needs::NONE
        }
    }

    /// Whether the field `f` is needed.
    pub const fn has(&self, f: Field) -> bool {
        self.fields & (1 << f.index()) != 0
    }
}

impl std::ops::BitOr for Needs {
    type Output = Needs;
    fn bitor(self, o: Needs) -> Needs {
        Needs {
            depth: self.depth || o.depth,
            force: self.force || o.force,
            markers: self.markers || o.markers,
            fields: self.fields | o.fields,
        }
    }
}

/// What the writers read: the result of one evaluation.
#[derive(Clone, Copy, Debug)]
pub struct Frame<'a> {
    /// Depth image as the camera sees it (m, positive into the gel), when an output needs
    /// it; else empty.
    pub depth: &'a [f64],
    /// The surface's depth on the orthographic pixel grid, the one the images of
    /// [`Seen::Resampled`] outputs are written on (`depth` itself for the orthographic
    /// camera).
    pub surface: &'a [f64],
    /// Lowest indenter surface per pixel (sensor-frame z, m), `+inf` where none.
    pub zmin: &'a [f64],
    /// Total force of the gel on the indenters (N, sensor frame); zero unless needed.
    pub force: Vector3<f64>,
    /// Each [`Field`] at its index (H x W x channels), when an output needs it; else
    /// empty.
    pub fields: [&'a [f64]; Field::ALL.len()],
    /// The images' pixel grid.
    pub grid: &'a PixelGrid,
    /// The markers and their displacements, when an output needs them; else empty.
    pub markers: &'a Markers,
    /// The optical model of the `rgb` output.
    pub optics: &'a rgb::RgbModel,
}

/// One output of the table.
#[derive(Debug)]
pub struct OutputSpec {
    /// Name in the `outputs` attribute and in the Python package.
    pub name: &'static str,
    /// What it holds.
    pub doc: &'static str,
    /// Unit of its values.
    pub unit: &'static str,
    /// Its shape.
    pub shape: Shape,
    /// Whether it needs a gel with stiffness (not `physics="rigid"`).
    pub needs_gel: bool,
    /// What the evaluation computes for it.
    pub needs: Needs,
    /// How it follows a pinhole camera.
    pub seen: Seen,
    /// Writes the output from an evaluation's frame into its sensordata slice.
    pub write: fn(&Frame<'_>, &mut [f64]),
}

/// What an output's size depends on: the image and the marker grid of a configuration
/// ([`crate::config::Config::layout`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    /// Image width (pixels).
    pub width: usize,
    /// Image height (pixels).
    pub height: usize,
    /// Markers along x and y.
    pub markers: [usize; 2],
}

impl OutputSpec {
    /// Its dimensions for `layout`: `[H, W]`, `[H, W, C]`, `[n]` or `[NX * NY, n]`.
    pub fn dims(&self, layout: &Layout) -> Vec<usize> {
        match self.shape {
            Shape::Image { channels: 1 } => vec![layout.height, layout.width],
            Shape::Image { channels } => vec![layout.height, layout.width, channels],
            Shape::Vector(n) => vec![n],
            Shape::PerMarker(n) => vec![layout.markers[0] * layout.markers[1], n],
        }
    }

    /// Number of sensordata values for `layout`.
    pub fn len(&self, layout: &Layout) -> usize {
        // As `dims`' product, without making the vector (read at every frame).
        match self.shape {
            Shape::Image { channels } => layout.height * layout.width * channels,
            Shape::Vector(n) => n,
            Shape::PerMarker(n) => layout.markers[0] * layout.markers[1] * n,
        }
    }
}

/// One configured output: a row of [`TABLE`].
#[derive(Clone, Copy)]
pub struct Output(&'static OutputSpec);

impl Output {
    /// The indentation depth image.
    pub const DEPTH: Output = Output(&DEPTH);
    /// The total contact force.
    pub const FORCE: Output = Output(&FORCE);
    /// The contact mask.
    pub const CONTACT: Output = Output(&CONTACT);
    /// The RGB tactile image.
    pub const RGB: Output = Output(&RGB);
    /// The normal contact pressure image.
    pub const PRESSURE: Output = Output(&PRESSURE);
    /// The shear image.
    pub const SHEAR: Output = Output(&SHEAR);
    /// The markers.
    pub const MARKERS: Output = Output(&MARKERS);

    /// The output called `name`, if the table has one.
    pub fn named(name: &str) -> Option<Output> {
        TABLE.iter().find(|o| o.0.name == name).copied()
    }

    /// Its row of the table.
    pub fn spec(self) -> &'static OutputSpec {
        self.0
    }

    /// Its name.
    pub fn name(self) -> &'static str {
        self.0.name
    }
}

impl PartialEq for Output {
    fn eq(&self, other: &Self) -> bool {
        self.0.name == other.0.name
    }
}

impl Eq for Output {}

impl std::fmt::Debug for Output {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.0.name)
    }
}

/// Every output, in the order the documentation lists them.
pub const TABLE: [Output; 7] = [
    Output::DEPTH,
    Output::FORCE,
    Output::CONTACT,
    Output::RGB,
    Output::PRESSURE,
    Output::SHEAR,
    Output::MARKERS,
];

const DEPTH: OutputSpec = OutputSpec {
    name: "depth",
    doc: "indentation depth image, positive into the gel",
    unit: "m",
    shape: Shape::Image { channels: 1 },
    needs_gel: false,
    needs: Needs {
        depth: true,
        ..Needs::NONE
    },
    seen: Seen::AsWritten,
    write: |f, out| out.copy_from_slice(f.depth),
};

const FORCE: OutputSpec = OutputSpec {
    name: "force",
    doc: "total force of the gel on the indenters, sensor frame",
    unit: "N",
    shape: Shape::Vector(3),
    needs_gel: true,
    needs: Needs {
        force: true,
        ..Needs::NONE
    },
    seen: Seen::AsWritten,
    write: |f, out| out.copy_from_slice(f.force.as_slice()),
};

const CONTACT: OutputSpec = OutputSpec {
    name: "contact",
    doc: "contact mask: 1 where an indenter reaches below the undeformed gel face, else 0",
    unit: "1",
    shape: Shape::Image { channels: 1 },
    needs_gel: false,
    needs: Needs::NONE,
    seen: Seen::Resampled(Sampling::Nearest),
    write: |f, out| {
        for (c, &z) in out.iter_mut().zip(f.zmin) {
            *c = if z.is_finite() && z < 0.0 { 1.0 } else { 0.0 };
        }
    },
};

const RGB: OutputSpec = OutputSpec {
    name: "rgb",
    doc: "RGB image of a GelSight-type sensor: the deformed surface shaded by a red, a green \
          and a blue light over a uniform background, or by the calibrated gradient-to-colour \
          table and background of the 'optics' attribute; the flat gel shows the background; \
          with the markers output, the markers drawn as dark dots where the camera sees them",
    unit: "0..255",
    shape: Shape::Image {
        channels: rgb::CHANNELS,
    },
    needs_gel: false,
    needs: Needs {
        depth: true,
        ..Needs::NONE
    },
    seen: Seen::Resampled(Sampling::Bilinear),
    write: |f, out| {
        f.optics.render(f.grid, f.surface, out);
        f.markers.draw(f.grid, out);
    },
};

const PRESSURE: OutputSpec = OutputSpec {
    name: "pressure",
    doc: "normal contact pressure image of the gel on the indenters; integrates over the \
          image to the normal force (force z) where the contact lies inside it (orthographic \
          camera); rom: from its coarse gel",
    unit: "Pa",
    shape: Shape::Image { channels: 1 },
    needs_gel: true,
    needs: Needs::field(Field::Pressure),
    seen: Seen::Resampled(Sampling::Bilinear),
    write: |f, out| out.copy_from_slice(f.fields[Field::Pressure.index()]),
};

const SHEAR: OutputSpec = OutputSpec {
    name: "shear",
    doc: "in-plane displacement of the gel surface seen at each pixel, sensor frame x then y \
          (the depth image's inverse map; zero where the gel is undeformed); rom: from its \
          coarse gel",
    unit: "m",
    shape: Shape::Image { channels: 2 },
    needs_gel: true,
    needs: Needs::field(Field::Shear),
    seen: Seen::Resampled(Sampling::Bilinear),
    write: |f, out| out.copy_from_slice(f.fields[Field::Shear.index()]),
};

const MARKERS: OutputSpec = OutputSpec {
    name: "markers",
    doc: "the NX x NY markers of the 'markers' attribute, printed on the gel in a regular \
          grid over the image, in its reading order (first row at +y, first column at -x); \
          per marker: column and row of its image position X_m + u_xy(X_m) (pixels, \
          continuous, c at the centre of column c), then its displacement along x and y \
          (m); rom: from its coarse gel; orthographic camera only",
    unit: "px, px, m, m",
    shape: Shape::PerMarker(Markers::VALUES),
    needs_gel: true,
    needs: Needs {
        markers: true,
        ..Needs::NONE
    },
    seen: Seen::Refused,
    write: |f, out| f.markers.write(f.grid, out),
};

impl Needs {
    /// Nothing beyond the indenters' rigid surface.
    pub const NONE: Needs = Needs {
        depth: false,
        force: false,
        markers: false,
        fields: 0,
    };
}

/// The output table as JSON, for the Python package: per output its name, description,
/// unit, shape (`["H", "W"]`, `["H", "W", C]`, `[n]` or `["N", n]`, `N` the number of
/// markers) and whether it needs a gel model.
pub fn table_json() -> String {
    let rows: Vec<serde_json::Value> = TABLE
        .iter()
        .map(|o| {
            let s = o.spec();
            let shape = match s.shape {
                Shape::Image { channels: 1 } => serde_json::json!(["H", "W"]),
                Shape::Image { channels } => serde_json::json!(["H", "W", channels]),
                Shape::Vector(n) => serde_json::json!([n]),
                Shape::PerMarker(n) => serde_json::json!(["N", n]),
            };
            serde_json::json!({
                "name": s.name,
                "doc": s.doc,
                "unit": s.unit,
                "shape": shape,
                "needs_gel": s.needs_gel,
            })
        })
        .collect();
    serde_json::Value::Array(rows).to_string()
}

/// The output table as the README shows it (Markdown), between its `tacrom:outputs`
/// markers.
pub fn markdown_table() -> String {
    let mut out = String::from("| output | shape | unit | content |\n|---|---|---|---|\n");
    for o in TABLE {
        let s = o.spec();
        let shape = match s.shape {
            Shape::Image { channels: 1 } => "(H, W)".to_owned(),
            Shape::Image { channels } => format!("(H, W, {channels})"),
            Shape::Vector(n) => format!("({n},)"),
            Shape::PerMarker(n) => format!("(NX * NY, {n})"),
        };
        let gel = if s.needs_gel {
            " (not with `rigid`)"
        } else {
            ""
        };
        out.push_str(&format!(
            "| `{}` | {shape} | {} | {}{gel} |\n",
            s.name, s.unit, s.doc
        ));
    }
    out
}
