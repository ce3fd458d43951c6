//! The face and skin: skin tone with a little variation, eyes (sclera, iris, pupil), brows,
//! lips and the mouth line, placed from the eye joints and the jaw's weights.

use glam::Vec3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::landmarks::Landmarks;
use super::noise::fbm;
use super::palette::{self, Rgb, mix, scale};

/// The colours of a face.
#[derive(Clone, Debug)]
pub(crate) struct Face {
    pub skin: Rgb,
    pub lips: Rgb,
    pub iris: Rgb,
    pub brows: Rgb,
    pub blush: f32,
    pub brow_weight: f32,
    pub seed: u32,
}

impl Face {
    pub fn random(rng: &mut ChaCha8Rng, skin: Rgb, hair: Rgb, feminine: bool) -> Self {
        let lips = if feminine && rng.random_bool(0.35) {
            mix(skin, [0.6, 0.1, 0.15], rng.random_range(0.4..0.7))
        } else {
            mix(scale(skin, 0.85), [0.55, 0.25, 0.25], 0.35)
        };
        let brows = mix(scale(hair, 0.8), scale(skin, 0.4), 0.2);
        Self {
            skin,
            lips,
            iris: palette::iris(rng),
            brows,
            blush: rng.random_range(0.0..0.12),
            brow_weight: rng.random_range(0.8..1.3),
            seed: rng.random(),
        }
    }

    /// Skin colour at a body point, with a subtle mottling.
    pub fn skin_at(&self, p: Vec3) -> Rgb {
        scale(self.skin, 0.96 + 0.08 * fbm(p * 40.0, self.seed))
    }

    /// The colour of an eyeball point (`centre`: the eye joint in the rest pose).
    pub fn eye(&self, p: Vec3, centre: Vec3) -> Rgb {
        let d = (p - centre).normalize_or(Vec3::Z);
        let angle = d.z.clamp(-1.0, 1.0).acos();
        if angle < 0.22 {
            [0.04, 0.03, 0.03]
        } else if angle < 0.52 {
            scale(self.iris, 0.85 + 0.3 * (angle - 0.22) / 0.3)
        } else {
            [0.9, 0.88, 0.85]
        }
    }

    /// The colour of a point of the head's skin (`jaw`: its jaw weight, for the mouth line).
    pub fn head(&self, lm: &Landmarks, p: Vec3, jaw: f32) -> Rgb {
        let mut c = self.skin_at(p);
        let e = lm.eye_mid;
        let k = lm.eye_distance / 0.062;
        let front = p.z > e.z - 0.035 * k;
        if !front {
            return c;
        }
        let dx = p.x - e.x;
        // Mouth: lips around the lip line, the line itself dark (it opens with the jaw).
        let my = lm.mouth_y;
        let lip_half_width = 0.024 * k;
        let lx = (dx / lip_half_width).abs();
        if lx < 1.0 {
            let shape = (1.0 - lx * lx).sqrt();
            let upper = 0.0065 * k * shape;
            let lower = 0.0085 * k * shape;
            if p.y < my + upper + 0.0015 && p.y > my - lower - 0.004 {
                c = self.lips;
            }
            if jaw > 0.15 && jaw < 0.85 {
                c = mix([0.25, 0.08, 0.08], self.lips, 0.2);
            }
        }
        // Brows: an arch above each eye.
        for s in [-1.0f32, 1.0] {
            let ex = e.x + s * lm.eye_distance / 2.0;
            let bx = (p.x - ex) / (0.026 * k);
            if bx.abs() < 1.0 {
                let arch = e.y + (0.021 + 0.005 * (1.0 - bx * bx) - 0.002 * bx * s) * k;
                let half = 0.0032 * k * self.brow_weight * (1.0 - 0.5 * (bx * s).max(0.0));
                if (p.y - arch).abs() < half {
                    c = self.brows;
                }
            }
            // A darker rim around the eye opening (lashes, lid crease).
            let dist = Vec3::new(p.x - ex, (p.y - e.y) * 1.6, 0.0).length();
            if dist > 0.0125 * k && dist < 0.0165 * k && p.y > e.y - 0.003 * k {
                c = mix(c, [0.12, 0.08, 0.07], 0.55);
            }
            // Cheeks.
            let cheek = Vec3::new(p.x - ex - s * 0.01, p.y - (e.y - 0.032 * k), 0.0).length();
            c = mix(
                c,
                [0.85, 0.35, 0.35],
                self.blush * (1.0 - cheek / (0.02 * k)).max(0.0),
            );
        }
        c
    }
}
