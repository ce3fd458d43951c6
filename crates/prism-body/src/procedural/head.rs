//! The procedural head: a deformed ellipsoid (jaw, chin, nose, brow, ears, eye sockets) as a
//! function of the direction from its centre, plus the eyeballs.

use glam::Vec3;

use super::proportions::Proportions;

/// Radius of an eyeball.
pub(crate) const EYE_RADIUS: f32 = 0.012;

/// The head's shape parameters.
#[derive(Clone, Debug)]
pub(crate) struct Head {
    pub centre: Vec3,
    pub scale: f32,
    pub nose: f32,
    pub eye_spacing: f32,
}

/// A Gaussian bump on the unit sphere around `axis`, with angular widths `(sx, sy)` along the
/// horizontal and vertical directions.
fn bump(dir: Vec3, axis: Vec3, sx: f32, sy: f32) -> f32 {
    let a = axis.normalize();
    // Tangent coordinates of `dir` around `a`.
    let right = Vec3::Y.cross(a).normalize_or(Vec3::X);
    let up = a.cross(right);
    if dir.dot(a) <= 0.0 {
        return 0.0;
    }
    let x = dir.dot(right);
    let y = dir.dot(up);
    (-(x * x) / (2.0 * sx * sx) - (y * y) / (2.0 * sy * sy)).exp()
}

impl Head {
    pub fn new(p: &Proportions) -> Self {
        Self {
            centre: Vec3::new(0.0, p.head_centre_y, 0.004),
            scale: p.head_scale,
            nose: p.nose,
            eye_spacing: p.eye_spacing,
        }
    }

    /// Direction (from the centre) of the left eye; the right one is mirrored in x.
    fn eye_dir(&self) -> Vec3 {
        Vec3::new(0.36 * self.eye_spacing, 0.24, 0.93).normalize()
    }

    /// The head surface without the eye sockets, at unit direction `dir`, relative to the
    /// centre and before scaling.
    fn base_radius(&self, dir: Vec3) -> f32 {
        let (x, y, z) = (dir.x, dir.y, dir.z);
        // Half-axes: narrower in x; a longer back of the skull than front.
        let ax = 0.079 * (1.0 - 0.2 * (-y).max(0.0).powf(1.6)) * (1.0 + 0.03 * y.max(0.0));
        let ay = if y >= 0.0 { 0.118 } else { 0.108 };
        let az = if z >= 0.0 { 0.092 } else { 0.098 }
            * (1.0 - 0.12 * (-y).max(0.0).powi(2) * (z < 0.0) as u8 as f32);
        let mut r = 1.0 / ((x / ax).powi(2) + (y / ay).powi(2) + (z / az).powi(2)).sqrt();
        // Flatter face: pull the front sides back a little.
        r -= 0.006 * (x.abs() * z.max(0.0) * 2.0).min(1.0);
        // Nose (bridge to tip), chin, brow ridge, cheekbones, ears.
        r += 0.017 * self.nose * bump(dir, Vec3::new(0.0, -0.08, 1.0), 0.07, 0.16);
        r += 0.007 * self.nose * bump(dir, Vec3::new(0.0, -0.22, 1.0), 0.14, 0.07);
        r += 0.008 * bump(dir, Vec3::new(0.0, -1.2, 1.0), 0.3, 0.10);
        r += 0.005 * bump(dir, Vec3::new(0.0, 0.5, 1.0), 0.45, 0.06);
        r += 0.003 * bump(dir, Vec3::new(0.0, -0.72, 1.0), 0.2, 0.05);
        for s in [-1.0f32, 1.0] {
            r += 0.004 * bump(dir, Vec3::new(0.6 * s, 0.0, 0.8), 0.12, 0.08);
            r += 0.011 * bump(dir, Vec3::new(s, 0.1, -0.12), 0.07, 0.13);
        }
        r
    }

    /// Radius of the head surface along unit `dir` (relative to the centre, scaled).
    pub fn radius(&self, dir: Vec3) -> f32 {
        let mut r = self.base_radius(dir);
        let e = self.eye_dir();
        for m in [e, e * Vec3::new(-1.0, 1.0, 1.0)] {
            r -= 0.0075 * bump(dir, m, 0.13, 0.09);
        }
        r * self.scale
    }

    /// The head surface point in front of `(x, y)` (offsets from the centre, unscaled).
    pub fn front_point(&self, x: f32, y: f32) -> Vec3 {
        let d = Vec3::new(x, y, 0.09).normalize();
        self.centre + d * self.radius(d)
    }

    /// Height of the lip line (where the jaw's weights begin).
    pub fn mouth_y(&self) -> f32 {
        self.front_point(0.0, -0.0565 * self.scale).y
    }

    /// Centre of the left eyeball (mirror x for the right).
    pub fn eye_centre(&self) -> Vec3 {
        let d = self.eye_dir();
        self.centre + d * (self.base_radius(d) * self.scale - 0.0135)
    }

    /// The head as a UV sphere: `(positions, triangles)`, outward, poles at the top and bottom.
    pub fn mesh(&self, latitudes: usize, longitudes: usize) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        uv_sphere(latitudes, longitudes, |dir| {
            self.centre + dir * self.radius(dir)
        })
    }
}

/// A UV sphere with `latitudes` rings between the poles (+Y and -Y) and `longitudes` vertices
/// per ring, longitude 0 facing +Z, each vertex placed by `place(direction)`.
pub(crate) fn uv_sphere(
    latitudes: usize,
    longitudes: usize,
    place: impl Fn(Vec3) -> Vec3,
) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut pos = vec![place(Vec3::Y)];
    for i in 1..=latitudes {
        let theta = std::f32::consts::PI * i as f32 / (latitudes + 1) as f32;
        for j in 0..longitudes {
            let phi = std::f32::consts::TAU * j as f32 / longitudes as f32;
            let dir = Vec3::new(
                theta.sin() * phi.sin(),
                theta.cos(),
                theta.sin() * phi.cos(),
            );
            pos.push(place(dir));
        }
    }
    pos.push(place(-Vec3::Y));
    let n = longitudes as u32;
    let ring = |i: usize, j: u32| 1 + (i as u32) * n + j % n;
    let mut tris = Vec::new();
    for j in 0..n {
        tris.push([0, ring(0, j), ring(0, j + 1)]);
    }
    for i in 0..latitudes - 1 {
        for j in 0..n {
            let (a, b) = (ring(i, j), ring(i, j + 1));
            let (c, d) = (ring(i + 1, j + 1), ring(i + 1, j));
            tris.push([a, d, c]);
            tris.push([a, c, b]);
        }
    }
    let bottom = pos.len() as u32 - 1;
    for j in 0..n {
        tris.push([ring(latitudes - 1, j + 1), ring(latitudes - 1, j), bottom]);
    }
    (pos, tris)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uv_sphere_is_outward() {
        let (p, t) = uv_sphere(8, 12, |d| d);
        let vol: f32 = t
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| p[i as usize]);
                a.dot(b.cross(c)) / 6.0
            })
            .sum();
        assert!(vol > 3.5 && vol < 4.19, "{vol}");
    }

    #[test]
    fn eyes_protrude_from_their_sockets() {
        let head = Head::new(&Proportions::average());
        let e = head.eye_centre();
        let d = (e - head.centre).normalize();
        let front = (e - head.centre).length() + EYE_RADIUS;
        let surface = head.radius(d);
        assert!(
            front > surface + 0.002 && front < surface + 0.008,
            "{front} {surface}"
        );
    }
}
