//! Which geoms can press the gel, and where they are in the sensor frame.

use std::sync::Arc;

use nalgebra::{Point3, Vector3};

use super::sys;
use super::view::{pose, Data, Model};
use crate::config::{Config, Physics};
use crate::geometry::{self, Placed, Sdf};

/// A geom that may press the gel.
#[derive(Clone, Debug)]
struct Candidate {
    geom: usize,
    shape: Arc<dyn Sdf>,
    /// Radius of a sphere about the geom's origin that holds the whole shape.
    rbound: f64,
}

/// The sensor's view of the model: its site and the geoms that may touch its gel. Built
/// once per model; shared by every `mjData`.
#[derive(Clone, Debug)]
pub struct SceneSpec {
    site: usize,
    candidates: Vec<Candidate>,
    /// Radius of a sphere about the site that holds the whole gel.
    gel_radius: f64,
    /// The geom standing for the gel in MuJoCo's collision (`gel_geom`).
    gel_geom: Option<usize>,
}

/// What [`SceneSpec::gather`] found wrong this evaluation.
#[derive(Debug, Default)]
pub struct GatherIssues {
    /// Geoms skipped because their pose is not finite.
    pub nonfinite_geoms: Vec<usize>,
    /// The site's own pose is not finite.
    pub nonfinite_site: bool,
}

impl SceneSpec {
    /// Finds the candidate geoms for the sensor on `site`. Returns the spec and warnings
    /// (geom types that cannot be simulated).
    pub fn build(
        m: Model<'_>,
        site: usize,
        config: &Config,
    ) -> Result<(Self, Vec<String>), String> {
        let weld = |body: usize| m.body_weldid().get(body).copied().unwrap_or(-1);
        let site_body = *m.site_bodyid().get(site).ok_or("site id out of range")? as usize;
        let sensor_weld = weld(site_body);

        // Bodies named in `indenters`, each of which must exist.
        let mut allowed: Option<Vec<usize>> = None;
        if !config.indenters.is_empty() {
            let mut ids = Vec::new();
            for name in &config.indenters {
                let id = (0..m.name_bodyadr().len())
                    .find(|&b| m.body_name(b) == name)
                    .ok_or_else(|| {
                        format!(
                            "tacrom.tactile sensor '{}': attribute 'indenters' = \"{}\": no body \
                             named '{name}'",
                            config.name,
                            config.indenters.join(" ")
                        )
                    })?;
                ids.push(id);
            }
            allowed = Some(ids);
        }

        let gel_geom = match &config.gel_geom {
            None => None,
            Some(name) => {
                let fault = |why: &str| {
                    format!(
                        "tacrom.tactile sensor '{}': attribute 'gel_geom' = \"{name}\": {why}",
                        config.name
                    )
                };
                let g = (0..m.ngeom())
                    .find(|&g| m.geom_name(g) == name)
                    .ok_or_else(|| fault("no geom of that name"))?;
                if weld(m.geom_bodyid()[g] as usize) != sensor_weld {
                    return Err(fault(
                        "the geom is not on the sensor's body (nor welded to it); the gel's \
                         geom moves with the gel",
                    ));
                }
                Some(g)
            }
        };
        let mut candidates = Vec::new();
        let mut warnings = Vec::new();
        let types = m.geom_type();
        let bodies = m.geom_bodyid();
        for g in 0..m.ngeom() {
            let body = bodies[g] as usize;
            let eligible = match &allowed {
                Some(ids) => ids.contains(&body),
                // Geoms welded to the sensor never move against the gel.
                None => weld(body) != sensor_weld,
            };
            if !eligible {
                continue;
            }
            match shape_of_geom(m, g) {
                Ok(Some(shape)) => candidates.push(Candidate {
                    geom: g,
                    shape,
                    rbound: m.geom_rbound()[g],
                }),
                Ok(None) => {
                    // Planes and height fields are the floor and terrain: only warn when
                    // the user named the body explicitly.
                    if allowed.is_some()
                        || !matches!(types[g] as u32, sys::mjGEOM_PLANE | sys::mjGEOM_HFIELD)
                    {
                        warnings.push(format!(
                            "tacrom.tactile sensor '{}': geom '{}' (id {g}) has type {} which the \
                             sensor cannot simulate; it is ignored",
                            config.name,
                            m.geom_name(g),
                            geom_type_name(types[g])
                        ));
                    }
                }
                Err(e) => {
                    return Err(format!(
                        "tacrom.tactile sensor '{}': geom '{}' (id {g}): {e}",
                        config.name,
                        m.geom_name(g)
                    ))
                }
            }
        }
        if let Some(gel) = gel_geom {
            warnings.extend(torsion_warning(m, &config.name, gel, &candidates));
        }
        if config.physics != Physics::Rigid {
            // A mesh's distance grid that an earlier process kept, read now: its first
            // contact is then an ordinary frame (rigid reads no distances).
            for c in &candidates {
                c.shape.prepare();
            }
        }
        let [lx, ly, t] = config.size;
        let gel_radius = (0.25 * lx * lx + 0.25 * ly * ly + t * t).sqrt();
        Ok((
            SceneSpec {
                site,
                candidates,
                gel_radius,
                gel_geom,
            },
            warnings,
        ))
    }

    /// Number of candidate geoms.
    pub fn len(&self) -> usize {
        self.candidates.len()
    }

    /// Whether no geom can ever press the gel.
    pub fn is_empty(&self) -> bool {
        self.candidates.is_empty()
    }

    /// The geom standing for the gel in MuJoCo's collision (`gel_geom`), if any.
    pub fn gel_geom(&self) -> Option<usize> {
        self.gel_geom
    }

    /// The sensor's site.
    pub fn site(&self) -> usize {
        self.site
    }

    /// The candidates' shapes in order: the table by which a state names an indenter's
    /// shape (the same in every `mjData` of the model).
    pub fn shapes(&self) -> Vec<Arc<dyn Sdf>> {
        self.candidates.iter().map(|c| c.shape.clone()).collect()
    }

    /// The shape of `geom`, where it is a candidate.
    pub fn shape_of(&self, geom: usize) -> Option<Arc<dyn Sdf>> {
        self.candidates
            .iter()
            .find(|c| c.geom == geom)
            .map(|c| c.shape.clone())
    }

    /// Fills `out` with the candidate geoms near the gel, posed in the sensor frame, and
    /// `geoms` with their ids. Geoms whose bounding sphere cannot reach the gel's bounding
    /// sphere cost one distance test.
    pub fn gather(
        &self,
        m: Model<'_>,
        d: Data<'_>,
        out: &mut Vec<Placed>,
        geoms: &mut Vec<usize>,
    ) -> GatherIssues {
        out.clear();
        geoms.clear();
        let mut issues = GatherIssues::default();
        let s = self.site;
        let Some(site_pose) = pose(
            d.site_xpos(&m).get(3 * s..3 * s + 3).unwrap_or(&[]),
            d.site_xmat(&m).get(9 * s..9 * s + 9).unwrap_or(&[]),
        ) else {
            issues.nonfinite_site = true;
            return issues;
        };
        // The gel's centre, (0, 0, -T/2) in the site frame, is within gel_radius of the site.
        let site_origin = Point3::from(site_pose.translation.vector);
        let xpos = d.geom_xpos(&m);
        let xmat = d.geom_xmat(&m);
        for c in &self.candidates {
            let g = c.geom;
            let p = &xpos[3 * g..3 * g + 3];
            let centre = Point3::new(p[0], p[1], p[2]);
            let dist = (centre - site_origin).norm();
            if dist.is_finite() && dist > c.rbound + self.gel_radius {
                continue;
            }
            match pose(p, &xmat[9 * g..9 * g + 9]) {
                Some(geom_pose) => {
                    out.push(Placed {
                        shape: c.shape.clone(),
                        pose: site_pose.inv_mul(&geom_pose),
                    });
                    geoms.push(g);
                }
                None => issues.nonfinite_geoms.push(g),
            }
        }
        issues
    }
}

/// The contact dimension MuJoCo gives a pair of geoms `a` and `b` (`condim`: the geom of
/// higher `priority`'s, else the larger), where their collision masks let them collide
/// (`contype` of one against `conaffinity` of the other).
fn pair_condim(m: Model<'_>, a: usize, b: usize) -> Option<i32> {
    let (contype, conaffinity) = (m.geom_contype(), m.geom_conaffinity());
    if contype[a] & conaffinity[b] == 0 && contype[b] & conaffinity[a] == 0 {
        return None;
    }
    let (condim, priority) = (m.geom_condim(), m.geom_priority());
    Some(match priority[a].cmp(&priority[b]) {
        std::cmp::Ordering::Greater => condim[a],
        std::cmp::Ordering::Less => condim[b],
        std::cmp::Ordering::Equal => condim[a].max(condim[b]),
    })
}

/// The warning for a gel's geom `gel` (`gel_geom`) whose contacts with some `candidates`
/// have torsional (and rolling) friction rows (`condim` above 3), naming sensor `name`:
/// those rows stay MuJoCo's, soft, beside the gel's own resistance to a turn about its
/// normal (its contact points' tangential rows), and a held object turns on through them
/// (the gripper's hexagon: by a tenth of what was left at each step, for 2 s).
fn torsion_warning(
    m: Model<'_>,
    name: &str,
    gel: usize,
    candidates: &[Candidate],
) -> Option<String> {
    let torsional: Vec<String> = candidates
        .iter()
        .filter_map(|c| {
            let condim = pair_condim(m, gel, c.geom).filter(|&d| d > 3)?;
            Some(format!("'{}' ({condim})", m.geom_name(c.geom)))
        })
        .collect();
    let shown = 3;
    (!torsional.is_empty()).then(|| {
        let more = torsional.len().saturating_sub(shown);
        format!(
            "tacrom.tactile sensor '{name}': gel_geom '{}' meets geoms with condim above 3: \
             {}{}; MuJoCo's torsional friction acts there beside the gel's own resistance \
             to a turn, and lets a held object turn slowly. Give the gel's geom condim=\"3\" \
             and a priority above theirs",
            m.geom_name(gel),
            torsional[..torsional.len().min(shown)].join(", "),
            if more > 0 {
                format!(" and {more} more")
            } else {
                String::new()
            }
        )
    })
}

/// The SDF of geom `g`, `Ok(None)` for types the sensor cannot simulate.
fn shape_of_geom(m: Model<'_>, g: usize) -> Result<Option<Arc<dyn Sdf>>, String> {
    let size = &m.geom_size()[3 * g..3 * g + 3];
    let shape: Arc<dyn Sdf> = match m.geom_type()[g] as u32 {
        sys::mjGEOM_SPHERE => Arc::new(geometry::Sphere { radius: size[0] }),
        sys::mjGEOM_CAPSULE => Arc::new(geometry::Capsule::new(size[0], size[1])),
        sys::mjGEOM_CYLINDER => Arc::new(geometry::Cylinder::new(size[0], size[1])),
        sys::mjGEOM_ELLIPSOID => Arc::new(geometry::Ellipsoid::new(Vector3::new(
            size[0], size[1], size[2],
        ))),
        sys::mjGEOM_BOX => Arc::new(geometry::Cuboid::new(Vector3::new(
            size[0], size[1], size[2],
        ))),
        sys::mjGEOM_MESH => {
            let mesh = m.geom_dataid()[g];
            let Ok(mesh) = usize::try_from(mesh) else {
                return Err("mesh geom without mesh data".into());
            };
            mesh_shape(m, mesh)?
        }
        _ => return Ok(None),
    };
    Ok(Some(shape))
}

/// The SDF of mesh `id`, built once per process for identical mesh data.
fn mesh_shape(m: Model<'_>, id: usize) -> Result<Arc<dyn Sdf>, String> {
    let vadr = m.mesh_vertadr()[id] as usize;
    let vnum = m.mesh_vertnum()[id] as usize;
    let fadr = m.mesh_faceadr()[id] as usize;
    let fnum = m.mesh_facenum()[id] as usize;
    let verts = m
        .mesh_vert()
        .get(3 * vadr..3 * (vadr + vnum))
        .ok_or("mesh vertices out of range")?;
    let faces = m
        .mesh_face()
        .get(3 * fadr..3 * (fadr + fnum))
        .ok_or("mesh faces out of range")?;
    super::mesh_cache::get_or_build(verts, faces)
}

fn geom_type_name(t: i32) -> &'static str {
    match t as u32 {
        sys::mjGEOM_PLANE => "plane",
        sys::mjGEOM_HFIELD => "hfield",
        sys::mjGEOM_SDF => "sdf",
        _ => "unknown",
    }
}
