//! What MuJoCo's viewer shows of a sensor: the deformed gel surface as a bounded grid of
//! thin tiles coloured by depth, and the total force as an arrow at the contact centroid.
//!
//! Plain geometry, no MuJoCo: the functions here take the sensor's last depth image, its
//! site's pose in the world and a budget, and return geoms in the terms of `mjv_initGeom`
//! (type, size, world position, row-major rotation, colour). The plugin's `visualize`
//! callback (`mujoco::plugin`) writes them into the scene.
//!
//! Frames follow the sensor's: the site frame has its origin at the centre of the gel's top
//! face, +z out of the gel, the gel in `z in [-T, 0]`; image row 0 is the +y edge and column
//! 0 the -x edge ([`PixelGrid`]).

use nalgebra::{Isometry3, Matrix3, Point3, UnitQuaternion, Vector3};

use crate::geometry::PixelGrid;

/// Most geoms one sensor adds to a scene: at most `GEOM_BUDGET - 1` surface tiles and the
/// force arrow.
pub const GEOM_BUDGET: usize = 400;

/// Thickness of a surface tile, as a fraction of the gel's thickness.
const TILE_THICKNESS: f64 = 0.025;

/// Colour of the undeformed gel (linear RGB).
const GEL_RGB: [f32; 3] = [0.72, 0.74, 0.78];
/// Colour at half the frame's deepest indentation.
const MID_RGB: [f32; 3] = [0.15, 0.45, 0.95];
/// Colour at the frame's deepest indentation.
const DEEP_RGB: [f32; 3] = [0.95, 0.2, 0.1];

/// The kind of a drawn geom.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A thin box (`mjGEOM_BOX`) lying on the surface; `size` holds its half-extents.
    Tile,
    /// An arrow (`mjGEOM_ARROW`) from `pos` along the rotation's z axis; `size` holds
    /// (width, width, length), as `mjv_connector` sets it.
    Arrow,
}

/// One geom to draw, in world coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VisualGeom {
    /// Tile or arrow.
    pub kind: Kind,
    /// Half-extents (tile) or width, width, length (arrow), m.
    pub size: [f64; 3],
    /// Centre (tile) or tail (arrow), world frame, m.
    pub pos: [f64; 3],
    /// Orientation, row-major, world frame (MuJoCo's convention).
    pub mat: [f64; 9],
    /// Colour.
    pub rgba: [f32; 4],
}

/// The sensor's last surface: its depth image and the gel it lies on.
#[derive(Clone, Copy, Debug)]
pub struct Surface<'a> {
    /// Depth image (H x W, row-major, m, positive into the gel); may be empty when no
    /// configured output needed it.
    pub depth: &'a [f64],
    /// The image's pixel grid.
    pub grid: &'a PixelGrid,
    /// Gel thickness T (m).
    pub thickness: f64,
}

/// How the force arrow is drawn; MuJoCo's contact forces use `scale = vis.map.force /
/// stat.meanmass`, `width = vis.scale.forcewidth * stat.meansize` and
/// `rgba = vis.rgba.contactforce`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArrowStyle {
    /// Arrow length per newton (m/N).
    pub scale: f64,
    /// Arrow width (m).
    pub width: f64,
    /// Colour.
    pub rgba: [f32; 4],
}

/// The tile grid for `max_tiles` tiles over `grid`: `(columns, rows)` of tiles, their
/// aspect close to the field of view's, at most one tile per pixel, at most `max_tiles` in
/// all (none when `max_tiles` is 0 or the image is empty).
pub fn tile_counts(grid: &PixelGrid, max_tiles: usize) -> (usize, usize) {
    if max_tiles == 0 || grid.width == 0 || grid.height == 0 {
        return (0, 0);
    }
    let aspect = if grid.fov_x > 0.0 && grid.fov_y > 0.0 {
        grid.fov_y / grid.fov_x
    } else {
        grid.height as f64 / grid.width as f64
    };
    let rows = ((max_tiles as f64 * aspect).sqrt().floor() as usize).clamp(1, grid.height);
    let cols = (max_tiles / rows).clamp(1, grid.width);
    let rows = rows.min(max_tiles / cols).max(1);
    (cols, rows)
}

/// The pixels of tile `i` of `n` along an axis of `len` pixels: `[start, end)`.
fn block(i: usize, n: usize, len: usize) -> (usize, usize) {
    (i * len / n, (i + 1) * len / n)
}

/// A valid depth: finite, within `[0, t]`.
fn clean(d: f64, t: f64) -> f64 {
    if d.is_finite() {
        d.clamp(0.0, t)
    } else {
        0.0
    }
}

/// The depth image pooled into a grid of tiles: per tile, the deepest of its pixels.
#[derive(Clone, Debug, PartialEq)]
pub struct Tiles {
    /// Tiles along x (image columns).
    pub cols: usize,
    /// Tiles along y (image rows).
    pub rows: usize,
    /// Deepest indentation per tile (m, within `[0, T]`), row-major like the image.
    pub depth: Vec<f64>,
}

impl Tiles {
    /// Pools `surface` into at most `max_tiles` tiles ([`tile_counts`]), in one pass over
    /// the image; `None` when the image is empty or does not match its grid. Taking the
    /// deepest pixel loses no contact narrower than a tile, and the deepest tile is as
    /// deep as the image.
    pub fn pool(surface: &Surface<'_>, max_tiles: usize) -> Option<Self> {
        let grid = surface.grid;
        let (w, h, t) = (grid.width, grid.height, surface.thickness);
        // A NaN thickness fails `t > 0` too.
        let positive = t > 0.0;
        if surface.depth.len() != w * h || !positive {
            return None;
        }
        let (nx, ny) = tile_counts(grid, max_tiles);
        if nx == 0 {
            return None;
        }
        // Per band of rows, the deepest pixel of each column (element-wise, so it
        // vectorises), then of each tile's columns. `f64::max` passes over NaN; each
        // tile's value is cleaned once.
        let mut depth = vec![0.0_f64; nx * ny];
        let mut columns = vec![0.0_f64; w];
        for j in 0..ny {
            let (r0, r1) = block(j, ny, h);
            columns.fill(0.0);
            for row in surface.depth[r0 * w..r1 * w].chunks_exact(w) {
                for (m, &d) in columns.iter_mut().zip(row) {
                    *m = m.max(d);
                }
            }
            for (i, deepest) in depth[j * nx..(j + 1) * nx].iter_mut().enumerate() {
                let (c0, c1) = block(i, nx, w);
                *deepest = clean(columns[c0..c1].iter().copied().fold(0.0, f64::max), t);
            }
        }
        Some(Self {
            cols: nx,
            rows: ny,
            depth,
        })
    }

    /// The deepest tile's depth (m; 0 for a flat gel).
    pub fn max_depth(&self) -> f64 {
        self.depth.iter().copied().fold(0.0, f64::max)
    }
}

/// Every geom of one sensor, appended to `out`: the gel surface as at most
/// `budget - 1` tiles ([`surface_tiles`]) and, when `arrow` is given, the force (N, site
/// frame) as an arrow from the contact centroid ([`force_arrow`]); `site` is the site
/// frame in the world. Nothing when the surface is flat (or absent) and the force zero.
pub fn sensor_geoms(
    surface: &Surface<'_>,
    site: &Isometry3<f64>,
    budget: usize,
    arrow: Option<(&Vector3<f64>, &ArrowStyle)>,
    out: &mut Vec<VisualGeom>,
) {
    let tiles = Tiles::pool(surface, budget.saturating_sub(1));
    if let Some(tiles) = &tiles {
        surface_tiles(surface, tiles, site, out);
    }
    let Some((force, style)) = arrow.filter(|_| budget > 0) else {
        return;
    };
    // The centroid is looked for only when there is an arrow to draw from it.
    if let Some(mut geom) = force_arrow(&Point3::origin(), force, site, style) {
        let at = tiles
            .as_ref()
            .and_then(|t| contact_centroid(surface, t))
            .unwrap_or_else(Point3::origin);
        geom.pos = point_array(&(site * at));
        out.push(geom);
    }
}

/// Appends the gel surface as `tiles` (pooled from `surface`) to `out`, posed by `site`
/// (the site frame in the world). Each tile covers its block of pixels at the block's
/// deepest indentation, tilted along the surface's slope between tiles, its top face on
/// the surface; its colour goes from the gel's grey (flat) through blue to red at the
/// frame's deepest point. Appends nothing when the surface is flat.
pub fn surface_tiles(
    surface: &Surface<'_>,
    tiles: &Tiles,
    site: &Isometry3<f64>,
    out: &mut Vec<VisualGeom>,
) {
    let grid = surface.grid;
    let (w, h, t) = (grid.width, grid.height, surface.thickness);
    let (nx, ny) = (tiles.cols, tiles.rows);
    let pooled = &tiles.depth;
    let dmax = tiles.max_depth();
    if dmax <= 0.0 || nx == 0 || ny == 0 || pooled.len() != nx * ny {
        return;
    }
    let (px, py) = (grid.fov_x / w as f64, grid.fov_y / h as f64);
    // Tile edges and centres in the site frame; x grows with the column, y falls with the
    // row.
    let x_edges: Vec<f64> = (0..=nx)
        .map(|i| -0.5 * grid.fov_x + (i * w / nx) as f64 * px)
        .collect();
    let y_edges: Vec<f64> = (0..=ny)
        .map(|j| 0.5 * grid.fov_y - (j * h / ny) as f64 * py)
        .collect();
    let xc = |i: usize| 0.5 * (x_edges[i] + x_edges[i + 1]);
    let yc = |j: usize| 0.5 * (y_edges[j] + y_edges[j + 1]);
    let thick = TILE_THICKNESS * t;
    let z_axis = Vector3::z();
    for j in 0..ny {
        for i in 0..nx {
            let d = pooled[j * nx + i];
            // Slope of the surface z = -d by central differences between tiles (one-sided
            // at the edges, flat when there is a single tile along the axis).
            let (il, ir) = (i.saturating_sub(1), (i + 1).min(nx - 1));
            let (ju, jd) = (j.saturating_sub(1), (j + 1).min(ny - 1));
            let gx = if ir > il {
                -(pooled[j * nx + ir] - pooled[j * nx + il]) / (xc(ir) - xc(il))
            } else {
                0.0
            };
            let gy = if jd > ju {
                -(pooled[jd * nx + i] - pooled[ju * nx + i]) / (yc(jd) - yc(ju))
            } else {
                0.0
            };
            let normal = Vector3::new(-gx, -gy, 1.0).normalize();
            let tilt = UnitQuaternion::rotation_between(&z_axis, &normal)
                .unwrap_or_else(UnitQuaternion::identity);
            // The tile's top face on the surface point, its body inside the gel (at full
            // depth it rests on the gel's bonded bottom).
            let top = -d.min(t - thick);
            let centre = Point3::new(xc(i), yc(j), top) - normal * (0.5 * thick);
            let half = [
                0.5 * (x_edges[i + 1] - x_edges[i]) * (1.0 + gx * gx).sqrt(),
                0.5 * (y_edges[j] - y_edges[j + 1]) * (1.0 + gy * gy).sqrt(),
                0.5 * thick,
            ];
            out.push(VisualGeom {
                kind: Kind::Tile,
                size: half,
                pos: point_array(&(site * centre)),
                mat: row_major(&(site.rotation * tilt)),
                rgba: depth_colour(d / dmax),
            });
        }
    }
}

/// The contact centroid in the site frame: the surface points `(x, y, -d)` of the image
/// weighted by their depth `d`; `None` when the image is flat. Reads only the pixels of
/// the tiles that `tiles` (pooled from `surface`) found indented.
pub fn contact_centroid(surface: &Surface<'_>, tiles: &Tiles) -> Option<Point3<f64>> {
    let grid = surface.grid;
    let (w, h, t) = (grid.width, grid.height, surface.thickness.max(0.0));
    let (nx, ny) = (tiles.cols, tiles.rows);
    if surface.depth.len() != w * h || nx == 0 || tiles.depth.len() != nx * ny {
        return None;
    }
    let xs: Vec<f64> = (0..w).map(|c| grid.x(c)).collect();
    let (mut sum, mut sx, mut sy, mut sz) = (0.0, 0.0, 0.0, 0.0);
    for j in 0..ny {
        let (r0, r1) = block(j, ny, h);
        for i in (0..nx).filter(|&i| tiles.depth[j * nx + i] > 0.0) {
            let (c0, c1) = block(i, nx, w);
            for r in r0..r1 {
                let (mut rs, mut rx, mut rz) = (0.0, 0.0, 0.0);
                let row = &surface.depth[r * w + c0..r * w + c1];
                for (&d, &x) in row.iter().zip(&xs[c0..c1]) {
                    let d = clean(d, t);
                    rs += d;
                    rx += d * x;
                    rz += d * d;
                }
                sum += rs;
                sx += rx;
                sy += rs * grid.y(r);
                sz -= rz;
            }
        }
    }
    (sum > 0.0).then(|| Point3::new(sx / sum, sy / sum, sz / sum))
}

/// The arrow of `force` (N, site frame) from `at` (site frame), posed by `site`; `None`
/// when the force, scaled, is shorter than a nanometre or not finite.
pub fn force_arrow(
    at: &Point3<f64>,
    force: &Vector3<f64>,
    site: &Isometry3<f64>,
    style: &ArrowStyle,
) -> Option<VisualGeom> {
    let vec = site.rotation * force * style.scale;
    let len = vec.norm();
    if !(len.is_finite() && len > 1e-9 && at.coords.iter().all(|x| x.is_finite())) {
        return None;
    }
    // The minimal rotation taking z onto the arrow (half a turn about x when opposite).
    let rot = UnitQuaternion::rotation_between(&Vector3::z(), &vec).unwrap_or_else(|| {
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
    });
    Some(VisualGeom {
        kind: Kind::Arrow,
        size: [style.width, style.width, len],
        pos: point_array(&(site * at)),
        mat: row_major(&rot),
        rgba: style.rgba,
    })
}

/// Colour at `f` of the frame's deepest indentation (0: flat gel, 1: deepest).
fn depth_colour(f: f64) -> [f32; 4] {
    let f = if f.is_finite() {
        f.clamp(0.0, 1.0)
    } else {
        0.0
    } as f32;
    let (a, b, s) = if f < 0.5 {
        (GEL_RGB, MID_RGB, 2.0 * f)
    } else {
        (MID_RGB, DEEP_RGB, 2.0 * f - 1.0)
    };
    let mix = |k: usize| a[k] + (b[k] - a[k]) * s;
    [mix(0), mix(1), mix(2), 1.0]
}

fn point_array(p: &Point3<f64>) -> [f64; 3] {
    [p.x, p.y, p.z]
}

fn row_major(q: &UnitQuaternion<f64>) -> [f64; 9] {
    let m: Matrix3<f64> = q.to_rotation_matrix().into_inner();
    [
        m[(0, 0)],
        m[(0, 1)],
        m[(0, 2)],
        m[(1, 0)],
        m[(1, 1)],
        m[(1, 2)],
        m[(2, 0)],
        m[(2, 1)],
        m[(2, 2)],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, Vector3};

    fn grid(w: usize, h: usize) -> PixelGrid {
        PixelGrid {
            width: w,
            height: h,
            fov_x: 0.024,
            fov_y: 0.018,
        }
    }

    /// A site turned 90 degrees about z and lifted, so that frame mistakes show.
    fn site() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.1, -0.2, 0.3),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2),
        )
    }

    /// A dome of depth `peak` at site-frame (cx, cy), radius 3 mm.
    fn dome(g: &PixelGrid, cx: f64, cy: f64, peak: f64) -> Vec<f64> {
        let mut img = vec![0.0; g.width * g.height];
        for r in 0..g.height {
            for c in 0..g.width {
                let rr = ((g.x(c) - cx).powi(2) + (g.y(r) - cy).powi(2)).sqrt();
                img[r * g.width + c] = (peak * (1.0 - (rr / 0.003).powi(2))).max(0.0);
            }
        }
        img
    }

    fn local(site: &Isometry3<f64>, g: &VisualGeom) -> Point3<f64> {
        site.inverse_transform_point(&Point3::new(g.pos[0], g.pos[1], g.pos[2]))
    }

    #[test]
    fn tile_grid_stays_within_budget_and_follows_the_aspect() {
        let g = grid(320, 240);
        let (nx, ny) = tile_counts(&g, GEOM_BUDGET - 1);
        assert_eq!((nx, ny), (23, 17));
        assert!(nx * ny < GEOM_BUDGET);
        // Never more tiles than pixels, never more than asked.
        assert_eq!(tile_counts(&grid(4, 3), 399), (4, 3));
        assert_eq!(tile_counts(&grid(320, 240), 1), (1, 1));
        assert_eq!(tile_counts(&grid(320, 240), 0), (0, 0));
        for n in 1..500 {
            let (nx, ny) = tile_counts(&g, n);
            assert!(nx * ny <= n && nx >= 1 && ny >= 1, "{n}: {nx} x {ny}");
        }
    }

    fn style() -> ArrowStyle {
        ArrowStyle {
            scale: 0.01,
            width: 0.001,
            rgba: [0.9, 0.1, 0.1, 1.0],
        }
    }

    #[test]
    fn a_flat_or_empty_image_draws_nothing() {
        let g = grid(32, 24);
        let flat = vec![0.0; 32 * 24];
        let mut out = Vec::new();
        let s = Surface {
            depth: &flat,
            grid: &g,
            thickness: 0.004,
        };
        let zero = Vector3::zeros();
        sensor_geoms(&s, &site(), GEOM_BUDGET, Some((&zero, &style())), &mut out);
        assert!(out.is_empty());
        let tiles = Tiles::pool(&s, 399).unwrap();
        assert!(contact_centroid(&s, &tiles).is_none());
        let s = Surface {
            depth: &[],
            grid: &g,
            thickness: 0.004,
        };
        sensor_geoms(&s, &site(), GEOM_BUDGET, None, &mut out);
        assert!(out.is_empty());
        assert!(Tiles::pool(&s, 399).is_none());
    }

    #[test]
    fn never_more_geoms_than_the_budget() {
        let force = Vector3::new(0.0, 0.0, 1.0);
        for (w, h) in [(1, 1), (3, 2), (64, 48), (320, 240), (240, 320), (1000, 3)] {
            let g = grid(w, h);
            let img = vec![1e-4; w * h];
            let s = Surface {
                depth: &img,
                grid: &g,
                thickness: 0.004,
            };
            for budget in [0, 1, 2, 5, 100, GEOM_BUDGET] {
                let mut out = Vec::new();
                sensor_geoms(&s, &site(), budget, Some((&force, &style())), &mut out);
                assert!(out.len() <= budget, "{w} x {h}, {budget}: {}", out.len());
                if budget > 0 {
                    assert_eq!(out.last().map(|g| g.kind), Some(Kind::Arrow));
                }
                if budget > 1 {
                    assert!(out.len() > 1);
                }
            }
        }
    }

    #[test]
    fn tiles_cover_the_field_of_view_under_the_site_and_the_deepest_sits_at_the_press() {
        let g = grid(320, 240);
        // Off-centre: +x and +y of the site frame (right of and above the image centre).
        let (cx, cy, peak) = (0.004, 0.003, 0.8e-3);
        let img = dome(&g, cx, cy, peak);
        let s = Surface {
            depth: &img,
            grid: &g,
            thickness: 0.004,
        };
        let site = site();
        let mut out = Vec::new();
        sensor_geoms(&s, &site, GEOM_BUDGET, None, &mut out);
        assert_eq!(out.len(), 23 * 17);
        let mut area = 0.0;
        for tile in &out {
            assert_eq!(tile.kind, Kind::Tile);
            let p = local(&site, tile);
            assert!(p.x.abs() <= 0.012 && p.y.abs() <= 0.009, "{p}");
            assert!(p.z <= 0.0 && p.z >= -0.004, "{p}");
            assert!(tile.rgba.iter().all(|c| (0.0..=1.0).contains(c)));
            // Orthonormal rotations.
            let m = Matrix3::from_row_slice(&tile.mat);
            assert!((m * m.transpose() - Matrix3::identity()).norm() < 1e-9);
            area += 4.0 * tile.size[0] * tile.size[1];
        }
        // Together the tiles cover the field of view (slightly more where they tilt).
        assert!(area >= 0.024 * 0.018 * (1.0 - 1e-9), "{area}");
        assert!(area < 0.024 * 0.018 * 1.05, "{area}");
        // The deepest tile is as deep as the image, at the press.
        let deepest = out
            .iter()
            .min_by(|a, b| local(&site, a).z.total_cmp(&local(&site, b).z))
            .unwrap();
        let p = local(&site, deepest);
        let thick = TILE_THICKNESS * 0.004;
        let max = img.iter().copied().fold(0.0, f64::max);
        assert!(
            (p.z + max + 0.5 * thick).abs() < 0.1 * thick,
            "{p} vs {max}"
        );
        let (tx, ty) = (0.024 / 23.0, 0.018 / 17.0);
        assert!((p.x - cx).abs() <= tx && (p.y - cy).abs() <= ty, "{p}");
        assert_eq!(deepest.rgba, depth_colour(1.0));
        // Far from the press the gel is flat, grey and level with the top face.
        let corner = &out[0];
        let q = local(&site, corner);
        assert!(
            q.x < -0.011 && q.y > 0.008,
            "row 0 is +y, column 0 is -x: {q}"
        );
        assert!((q.z + 0.5 * thick).abs() < 1e-12);
        assert_eq!(corner.rgba, depth_colour(0.0));
        let m = Matrix3::from_row_slice(&corner.mat);
        let up = m * Vector3::z();
        assert!((up - site.rotation * Vector3::z()).norm() < 1e-12);
    }

    #[test]
    fn tiles_tilt_with_the_slope() {
        let g = grid(64, 48);
        let img = dome(&g, 0.0, 0.0, 1e-3);
        let s = Surface {
            depth: &img,
            grid: &g,
            thickness: 0.004,
        };
        let id = Isometry3::identity();
        let mut out = Vec::new();
        sensor_geoms(&s, &id, GEOM_BUDGET, None, &mut out);
        // A tile on the dome's -x flank faces +x (the surface dips towards the centre).
        let flank = out
            .iter()
            .find(|t| {
                let p = local(&id, t);
                p.x < -0.001 && p.x > -0.0025 && p.y.abs() < 0.0006
            })
            .unwrap();
        let n = Matrix3::from_row_slice(&flank.mat) * Vector3::z();
        assert!(n.x > 0.05 && n.z > 0.5, "{n}");
    }

    #[test]
    fn non_finite_and_out_of_range_depths_are_clamped() {
        let g = grid(8, 6);
        let mut img = vec![0.0; 48];
        img[0] = f64::NAN;
        img[1] = f64::INFINITY;
        img[2] = -1.0;
        img[20] = 1.0; // deeper than the gel
        let s = Surface {
            depth: &img,
            grid: &g,
            thickness: 0.004,
        };
        let mut out = Vec::new();
        sensor_geoms(&s, &Isometry3::identity(), GEOM_BUDGET, None, &mut out);
        assert_eq!(out.len(), 48);
        for t in &out {
            assert!(t
                .pos
                .iter()
                .chain(&t.mat)
                .chain(&t.size)
                .all(|x| x.is_finite()));
            assert!(t.pos[2] >= -0.004 - 1e-12);
        }
        let tiles = Tiles::pool(&s, 399).unwrap();
        assert_eq!(tiles.max_depth(), 0.004);
        let c = contact_centroid(&s, &tiles).unwrap();
        assert!((c.z + 0.004).abs() < 1e-12);
    }

    #[test]
    fn the_arrow_points_along_the_force_from_the_centroid() {
        let g = grid(64, 48);
        let img = dome(&g, 0.004, -0.002, 1e-3);
        let s = Surface {
            depth: &img,
            grid: &g,
            thickness: 0.004,
        };
        let c = contact_centroid(&s, &Tiles::pool(&s, 399).unwrap()).unwrap();
        assert!(
            (c.x - 0.004).abs() < 2e-4 && (c.y + 0.002).abs() < 2e-4,
            "{c}"
        );
        assert!(c.z < 0.0 && c.z > -1e-3);
        // The centroid of the pixels the tiles found is the centroid of the whole image.
        let all = Tiles {
            cols: 1,
            rows: 1,
            depth: vec![1.0],
        };
        let c_all = contact_centroid(&s, &all).unwrap();
        assert!((c - c_all).norm() < 1e-12);

        let site = site();
        let f = Vector3::new(0.3, 0.0, 2.0);
        let mut out = Vec::new();
        sensor_geoms(&s, &site, GEOM_BUDGET, Some((&f, &style())), &mut out);
        let a = out.last().unwrap();
        assert_eq!(a.kind, Kind::Arrow);
        assert_eq!(out.iter().filter(|g| g.kind == Kind::Arrow).count(), 1);
        assert!((local(&site, a) - c).norm() < 1e-12);
        let dir = Matrix3::from_row_slice(&a.mat) * Vector3::z();
        let want = (site.rotation * f).normalize();
        assert!((dir - want).norm() < 1e-12, "{dir} vs {want}");
        assert!((a.size[2] - f.norm() * 0.01).abs() < 1e-12);
        assert_eq!(a.size[0], 0.001);
        // Straight down works too; no force, no arrow.
        let down = force_arrow(&c, &Vector3::new(0.0, 0.0, -1.0), &site, &style()).unwrap();
        let dir = Matrix3::from_row_slice(&down.mat) * Vector3::z();
        assert!((dir + Vector3::z()).norm() < 1e-12);
        assert!(force_arrow(&c, &Vector3::zeros(), &site, &style()).is_none());
        assert!(force_arrow(&c, &Vector3::new(f64::NAN, 0.0, 1.0), &site, &style()).is_none());
    }
}
