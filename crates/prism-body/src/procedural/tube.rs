//! Closed tubes: straight generalized cylinders with superellipse cross-sections and rounded
//! caps, the building block of the procedural body (limbs, fingers, torso, neck, feet).

use glam::Vec3;

/// A cross-section of a tube at axial position `s` (metres from the tube's origin): its extent
/// towards `+e1`, `-e1`, `+e2`, `-e2`, the superellipse exponent (2 = ellipse, larger = boxier),
/// and an offset of its centre along `e1` and `e2`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Section {
    pub s: f32,
    pub e1_pos: f32,
    pub e1_neg: f32,
    pub e2_pos: f32,
    pub e2_neg: f32,
    pub exponent: f32,
    pub offset: [f32; 2],
}

impl Section {
    /// An elliptic section with half-axes `r1` (along `e1`) and `r2` (along `e2`).
    pub fn ellipse(s: f32, r1: f32, r2: f32) -> Self {
        Self {
            s,
            e1_pos: r1,
            e1_neg: r1,
            e2_pos: r2,
            e2_neg: r2,
            exponent: 2.0,
            offset: [0.0, 0.0],
        }
    }

    fn lerp(&self, other: &Section, t: f32) -> Section {
        let l = |a: f32, b: f32| a + (b - a) * t;
        Section {
            s: l(self.s, other.s),
            e1_pos: l(self.e1_pos, other.e1_pos),
            e1_neg: l(self.e1_neg, other.e1_neg),
            e2_pos: l(self.e2_pos, other.e2_pos),
            e2_neg: l(self.e2_neg, other.e2_neg),
            exponent: l(self.exponent, other.exponent),
            offset: [
                l(self.offset[0], other.offset[0]),
                l(self.offset[1], other.offset[1]),
            ],
        }
    }

    fn scaled(&self, k: f32) -> Section {
        Section {
            e1_pos: self.e1_pos * k,
            e1_neg: self.e1_neg * k,
            e2_pos: self.e2_pos * k,
            e2_neg: self.e2_neg * k,
            ..*self
        }
    }
}

/// A straight tube from `origin` along `axis`, with key sections (sorted by `s`) interpolated
/// smoothly (cubic Hermite with Catmull-Rom slopes), closed by ellipsoidal caps of the given
/// lengths (0 for a flat cap).
#[derive(Clone, Debug)]
pub(crate) struct Tube {
    pub origin: Vec3,
    pub axis: Vec3,
    /// First cross-section direction (perpendicular to `axis`).
    pub e1: Vec3,
    pub sections: Vec<Section>,
    pub rings: usize,
    pub segments: usize,
    pub start_cap: f32,
    pub end_cap: f32,
    /// Rings of each cap (between the tube's end ring and the pole).
    pub cap_rings: [usize; 2],
}

/// A vertex of a tube: its position and where it lies on the tube.
#[derive(Clone, Copy, Debug)]
pub(crate) struct TubeVertex {
    pub position: Vec3,
    /// Axial coordinate (may lie outside the sections' range on the caps).
    pub s: f32,
    /// Unit direction from the axis point (the cap poles point along the axis).
    pub radial: Vec3,
}

impl Tube {
    /// The interpolated cross-section at `s` (clamped to the key sections).
    pub fn section_at(&self, s: f32) -> Section {
        let k = &self.sections;
        if s <= k[0].s {
            return Section { s, ..k[0] };
        }
        let last = k.len() - 1;
        if s >= k[last].s {
            return Section { s, ..k[last] };
        }
        let i = (0..last).find(|&i| s < k[i + 1].s).unwrap_or(last - 1);
        let (a, b) = (&k[i], &k[i + 1]);
        let t = (s - a.s) / (b.s - a.s);
        // Catmull-Rom: smooth values through the keys, with neighbours as slope references.
        let prev = if i == 0 { a } else { &k[i - 1] };
        let next = if i + 1 == last { b } else { &k[i + 2] };
        let h00 = 2.0 * t * t * t - 3.0 * t * t + 1.0;
        let h10 = t * t * t - 2.0 * t * t + t;
        let h01 = -2.0 * t * t * t + 3.0 * t * t;
        let h11 = t * t * t - t * t;
        let span = b.s - a.s;
        let slope = |p: f32, ps: f32, q: f32, qs: f32| {
            if qs > ps {
                (q - p) / (qs - ps) * span
            } else {
                0.0
            }
        };
        let f = |g: fn(&Section) -> f32| {
            let m0 = slope(g(prev), prev.s, g(b), b.s);
            let m1 = slope(g(a), a.s, g(next), next.s);
            h00 * g(a) + h10 * m0 + h01 * g(b) + h11 * m1
        };
        let mut out = a.lerp(b, t);
        out.s = s;
        out.e1_pos = f(|x| x.e1_pos).max(1e-4);
        out.e1_neg = f(|x| x.e1_neg).max(1e-4);
        out.e2_pos = f(|x| x.e2_pos).max(1e-4);
        out.e2_neg = f(|x| x.e2_neg).max(1e-4);
        out.offset = [f(|x| x.offset[0]), f(|x| x.offset[1])];
        out
    }

    /// Vertices and outward-facing triangles (counter-clockwise seen from outside).
    pub fn build(&self) -> (Vec<TubeVertex>, Vec<[u32; 3]>) {
        let axis = self.axis.normalize();
        let e1 = (self.e1 - self.e1.dot(axis) * axis).normalize();
        let e2 = axis.cross(e1);
        let s0 = self.sections[0].s;
        let s1 = self.sections[self.sections.len() - 1].s;

        // (s, section) of every ring, start cap, body, end cap.
        let mut rings: Vec<(f32, Section)> = Vec::new();
        let first = self.section_at(s0);
        let last = self.section_at(s1);
        if self.start_cap > 0.0 {
            let n = self.cap_rings[0] + 1;
            for k in 1..n {
                let a = std::f32::consts::FRAC_PI_2 * k as f32 / n as f32;
                rings.push((s0 - self.start_cap * a.cos(), first.scaled(a.sin())));
            }
        }
        for i in 0..self.rings {
            let s = s0 + (s1 - s0) * i as f32 / (self.rings - 1) as f32;
            rings.push((s, self.section_at(s)));
        }
        if self.end_cap > 0.0 {
            let n = self.cap_rings[1] + 1;
            for k in (1..n).rev() {
                let a = std::f32::consts::FRAC_PI_2 * k as f32 / n as f32;
                rings.push((s1 + self.end_cap * a.cos(), last.scaled(a.sin())));
            }
        }

        let n = self.segments;
        let mut verts = Vec::with_capacity(rings.len() * n + 2);
        let centre = |s: f32, sec: &Section| {
            self.origin + axis * s + e1 * sec.offset[0] + e2 * sec.offset[1]
        };
        for (s, sec) in &rings {
            let c = centre(*s, sec);
            let p = 2.0 / sec.exponent;
            for j in 0..n {
                let phi = std::f32::consts::TAU * j as f32 / n as f32;
                let (sn, cs) = phi.sin_cos();
                let r1 = if cs >= 0.0 { sec.e1_pos } else { sec.e1_neg };
                let r2 = if sn >= 0.0 { sec.e2_pos } else { sec.e2_neg };
                let x = cs.signum() * cs.abs().powf(p) * r1;
                let y = sn.signum() * sn.abs().powf(p) * r2;
                let position = c + e1 * x + e2 * y;
                let radial = (e1 * cs + e2 * sn).normalize();
                verts.push(TubeVertex {
                    position,
                    s: *s,
                    radial,
                });
            }
        }
        let mut tris = Vec::with_capacity(rings.len() * n * 2 + 2 * n);
        for i in 0..rings.len() - 1 {
            for j in 0..n {
                let a = (i * n + j) as u32;
                let b = (i * n + (j + 1) % n) as u32;
                let c = ((i + 1) * n + (j + 1) % n) as u32;
                let d = ((i + 1) * n + j) as u32;
                tris.push([a, b, c]);
                tris.push([a, c, d]);
            }
        }
        // Poles.
        let start_s = s0 - self.start_cap;
        let start = verts.len() as u32;
        verts.push(TubeVertex {
            position: centre(start_s, &first),
            s: start_s,
            radial: -axis,
        });
        for j in 0..n {
            tris.push([start, ((j + 1) % n) as u32, j as u32]);
        }
        let end_s = s1 + self.end_cap;
        let end = verts.len() as u32;
        verts.push(TubeVertex {
            position: centre(end_s, &last),
            s: end_s,
            radial: axis,
        });
        let base = (rings.len() - 1) * n;
        for j in 0..n {
            tris.push([(base + j) as u32, (base + (j + 1) % n) as u32, end]);
        }
        (verts, tris)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_capped_cylinder_is_closed_and_outward() {
        let tube = Tube {
            origin: Vec3::ZERO,
            axis: Vec3::X,
            e1: Vec3::Y,
            sections: vec![
                Section::ellipse(0.0, 1.0, 1.0),
                Section::ellipse(2.0, 1.0, 1.0),
            ],
            rings: 5,
            segments: 24,
            start_cap: 1.0,
            end_cap: 0.5,
            cap_rings: [5, 3],
        };
        let (v, t) = tube.build();
        // Signed volume by the divergence theorem: a cylinder of length 2 plus a hemisphere
        // (2/3 pi) and a half-ellipsoid (1/3 pi), a bit less for the polygonal approximation.
        let vol: f32 = t
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| v[i as usize].position);
                a.dot(b.cross(c)) / 6.0
            })
            .sum();
        let exact = std::f32::consts::PI * (2.0 + 2.0 / 3.0 + 1.0 / 3.0);
        assert!(vol > 0.93 * exact && vol < exact, "{vol} vs {exact}");
        // Every edge is shared by exactly two triangles (closed surface).
        let mut edges = std::collections::HashMap::new();
        for f in &t {
            for k in 0..3 {
                let (a, b) = (f[k].min(f[(k + 1) % 3]), f[k].max(f[(k + 1) % 3]));
                *edges.entry((a, b)).or_insert(0) += 1;
            }
        }
        assert!(edges.values().all(|&c| c == 2));
    }
}
