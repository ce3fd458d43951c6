//! Hair: styles, the hair cap on the scalp (the head surface pushed out, hair-coloured) and the
//! extra geometry of longer styles (a sheet down the back, a ponytail, a bun), skinned to the
//! head and upper spine.

use glam::Vec3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::geometry::{Material, Piece, RadialProfile, grid_triangles, sweep};
use super::landmarks::Landmarks;
use super::noise::fbm;
use super::palette::{self, Rgb, scale};
use prism_body::joint;

/// A hair style.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum HairStyle {
    Bald,
    Buzz,
    Short,
    Curly,
    Bob,
    Long,
    Ponytail,
    Bun,
}

#[derive(Clone, Debug)]
pub(crate) struct Hair {
    pub style: HairStyle,
    pub color: Rgb,
    /// Thickness of the cap on the crown.
    pub volume: f32,
    /// How far the front hairline recedes (metres).
    pub recession: f32,
    /// Bottom of long hair below the neck base (metres).
    pub length: f32,
    pub seed: u32,
}

impl Hair {
    pub fn random(rng: &mut ChaCha8Rng, feminine: bool) -> Self {
        let style = if feminine {
            [
                HairStyle::Long,
                HairStyle::Long,
                HairStyle::Bob,
                HairStyle::Ponytail,
                HairStyle::Bun,
                HairStyle::Curly,
                HairStyle::Short,
            ][rng.random_range(0..7)]
        } else {
            [
                HairStyle::Short,
                HairStyle::Short,
                HairStyle::Buzz,
                HairStyle::Bald,
                HairStyle::Curly,
                HairStyle::Bob,
                HairStyle::Long,
            ][rng.random_range(0..7)]
        };
        let volume = match style {
            HairStyle::Bald => 0.0,
            HairStyle::Buzz => 0.003,
            HairStyle::Curly => rng.random_range(0.025..0.045),
            HairStyle::Ponytail | HairStyle::Bun => rng.random_range(0.006..0.01),
            _ => rng.random_range(0.01..0.022),
        };
        Self {
            style,
            color: palette::hair(rng),
            volume,
            recession: if feminine {
                0.0
            } else {
                rng.random_range(0.0..0.02)
            },
            length: rng.random_range(0.02..0.22),
            seed: rng.random(),
        }
    }

    /// The hairline height at horizontal angle `a` around the head (0 front, pi back).
    fn hairline(&self, lm: &Landmarks, a: f32) -> f32 {
        let e = lm.eye_mid.y;
        let s = lm.eye_distance / 0.062;
        let a = a.abs();
        let front = e + (0.05 + self.recession) * s;
        let side = e + 0.012 * s;
        let back = e - 0.06 * s;
        let t1 = ((a - 0.55) / 0.7).clamp(0.0, 1.0);
        let t2 = ((a - 1.5) / 0.9).clamp(0.0, 1.0);
        let y = front + (side - front) * t1;
        y + (back - y) * t2
    }

    /// Hair on the scalp at `p` (a head point, shaped rest frame): its colour and how far it
    /// stands off the skin, or `None` for bare skin.
    pub fn scalp(&self, lm: &Landmarks, p: Vec3) -> Option<(Rgb, f32)> {
        if self.style == HairStyle::Bald && p.y > lm.eye_mid.y + 0.045 {
            return None;
        }
        let q = p - lm.head_centre;
        let a = q.x.atan2(q.z);
        let line = self.hairline(lm, a);
        // The ears stay uncovered by short styles.
        let ear = a.abs() > 1.25
            && a.abs() < 1.95
            && p.y < lm.eye_mid.y + 0.02
            && p.y > lm.eye_mid.y - 0.05;
        let long = matches!(self.style, HairStyle::Long | HairStyle::Bob);
        if p.y < line || (ear && !long) {
            return None;
        }
        if self.style == HairStyle::Bald && p.y < lm.eye_mid.y - 0.04 {
            return None;
        }
        let above = p.y - line;
        let taper = (above / 0.03).clamp(0.0, 1.0);
        let crown = (q.y / 0.1).clamp(0.3, 1.0);
        let n = fbm(p * 60.0, self.seed);
        let mut thickness = self.volume * taper * crown;
        if self.style == HairStyle::Curly {
            thickness *= 0.75 + 0.5 * n;
        }
        let streak = fbm(
            Vec3::new(q.x.atan2(q.y) * 30.0, p.y * 8.0, 0.0),
            self.seed ^ 7,
        );
        let mut c = scale(self.color, 0.8 + 0.35 * streak);
        if matches!(self.style, HairStyle::Buzz | HairStyle::Bald) {
            c = scale(self.color, 0.9);
        }
        Some((c, thickness))
    }

    /// Extra geometry of the style (shaped rest frame), skinned to the head and upper spine.
    pub fn pieces(&self, lm: &Landmarks, body: &RadialProfile) -> Piece {
        let mut out = Piece::default();
        match self.style {
            HairStyle::Long | HairStyle::Bob => out.append(self.sheet(lm, body)),
            HairStyle::Ponytail => out.append(self.ponytail(lm, body)),
            HairStyle::Bun => out.append(self.bun(lm)),
            _ => {}
        }
        out
    }

    /// The colour of extra hair geometry at rest point `p`: streaks along the strands.
    pub fn strand_color(&self, lm: &Landmarks, p: Vec3) -> Rgb {
        let q = p - lm.head_centre;
        let a = q.x.atan2(q.z);
        let streak = fbm(Vec3::new(a * 40.0, p.y * 3.0, 0.0), self.seed ^ 7);
        scale(self.color, 0.75 + 0.4 * streak)
    }

    fn skin_weights(lm: &Landmarks, y: f32) -> Vec<(usize, f32)> {
        let w = ((y - (lm.neck_base_y - 0.02)) / 0.12).clamp(0.0, 1.0);
        let w = w * w * (3.0 - 2.0 * w);
        let mut out = Vec::new();
        if w > 0.0 {
            out.push((joint::HEAD, w));
        }
        if w < 1.0 {
            out.push((joint::SPINE3, 1.0 - w));
        }
        out
    }

    /// Hair falling around the back and sides of the head: a thick sheet following the head,
    /// neck and back at a distance.
    fn sheet(&self, lm: &Landmarks, body: &RadialProfile) -> Piece {
        let top = lm.eye_mid.y + 0.02;
        let bottom = if self.style == HairStyle::Bob {
            lm.mouth_y - 0.03
        } else {
            lm.neck_base_y - 0.04 - self.length
        };
        let rows = 30;
        let cols = 31;
        let thick = self.volume.max(0.012);
        let mut positions = Vec::new();
        let mut weights = Vec::new();
        for i in 0..rows {
            let t = i as f32 / (rows - 1) as f32;
            let y = top + (bottom - top) * t;
            // Angular half-width around the back: wide at the head, narrower down the back.
            let below_neck = ((lm.neck_base_y + 0.02 - y) / 0.08).clamp(0.0, 1.0);
            let half = 2.05 - 0.95 * below_neck;
            let taper = 1.0 - 0.5 * t * t;
            // Outer surface then inner surface (reversed), a closed crescent.
            let mut ring = Vec::new();
            for j in 0..cols {
                let a = std::f32::consts::PI + half * (2.0 * j as f32 / (cols - 1) as f32 - 1.0);
                let r = body.at(y, a) + 0.004 + thick * taper;
                ring.push((a, r));
            }
            for j in (0..cols).rev() {
                let a = std::f32::consts::PI + half * (2.0 * j as f32 / (cols - 1) as f32 - 1.0);
                let r = body.at(y, a)
                    + if y > lm.neck_base_y + 0.06 {
                        -0.006
                    } else {
                        0.003
                    };
                ring.push((a, r));
            }
            for (a, r) in ring {
                let p = body.point(y, a, r);
                positions.push(p);
                weights.push(Self::skin_weights(lm, y));
            }
        }
        let material = vec![Material::Hair; positions.len()];
        let n = 2 * cols;
        // Rows go down and columns run around the crescent: flip the grid's winding so that
        // the outer side faces out.
        let mut triangles: Vec<[u32; 3]> = grid_triangles(rows, n, false, true)
            .into_iter()
            .map(|[a, b, c]| [a, c, b])
            .collect();
        // Close the top and bottom edges with strips between the outer and inner rows.
        for (row, flip) in [(0usize, true), (rows - 1, false)] {
            let base = (row * n) as u32;
            for j in 0..cols as u32 - 1 {
                let o0 = base + j;
                let o1 = base + j + 1;
                let i0 = base + (n as u32 - 1 - j);
                let i1 = base + (n as u32 - 2 - j);
                if flip {
                    triangles.push([o0, o1, i1]);
                    triangles.push([o0, i1, i0]);
                } else {
                    triangles.push([o0, i1, o1]);
                    triangles.push([o0, i0, i1]);
                }
            }
        }
        Piece {
            positions,
            triangles,
            weights,
            material,
        }
    }

    fn ponytail(&self, lm: &Landmarks, body: &RadialProfile) -> Piece {
        let start_y = lm.eye_mid.y - 0.005;
        let back = std::f32::consts::PI;
        let length = 0.12 + self.length;
        let n = 12;
        let mut centres = Vec::new();
        let mut radii = Vec::new();
        for i in 0..n {
            let t = i as f32 / (n - 1) as f32;
            let y = start_y - length * t;
            let r = 0.022 * (1.0 - 0.6 * t) + 0.006 * (std::f32::consts::PI * t).sin();
            let out = body.at(y, back) + r + 0.01 + 0.02 * (1.0 - t) * (1.0 - t);
            centres.push(body.point(y, back, out));
            radii.push(r);
        }
        let (positions, triangles, ring) = sweep(&centres, &radii, 10);
        let material = vec![Material::Hair; positions.len()];
        let weights = ring
            .iter()
            .map(|&i| Self::skin_weights(lm, centres[i].y))
            .collect();
        Piece {
            positions,
            triangles,
            weights,
            material,
        }
    }

    fn bun(&self, lm: &Landmarks) -> Piece {
        let centre = lm.head_centre + Vec3::new(0.0, 0.085, -0.06) * (lm.eye_distance / 0.062);
        let r = 0.038;
        let n = 9;
        let centres: Vec<Vec3> = (0..n)
            .map(|i| centre + Vec3::new(0.0, r * (1.0 - 2.0 * i as f32 / (n - 1) as f32), 0.0))
            .collect();
        let radii: Vec<f32> = (0..n)
            .map(|i| {
                let t = 2.0 * i as f32 / (n - 1) as f32 - 1.0;
                r * (1.0 - t * t).max(0.0).sqrt().max(0.2)
            })
            .collect();
        let (positions, triangles, _) = sweep(&centres, &radii, 12);
        let material = vec![Material::Hair; positions.len()];
        let weights = positions.iter().map(|_| vec![(joint::HEAD, 1.0)]).collect();
        Piece {
            positions,
            triangles,
            weights,
            material,
        }
    }
}
