//! Clothes: what a person wears (drawn at random) and, for a point of the body, which garment
//! covers it, its colour (with patterns) and how far the cloth stands off the skin.

use glam::Vec3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::landmarks::{Landmarks, Region};
use super::noise::fbm;
use super::palette::{self, Rgb, mix, scale};

/// A fabric pattern, in metres on the garment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Pattern {
    Solid,
    HStripes { period: f32, duty: f32 },
    VStripes { period: f32, duty: f32 },
    Checks { period: f32 },
    Plaid { period: f32 },
    Dots { period: f32, radius: f32 },
    Denim,
    Knit,
}

/// A fabric: a base colour, a second colour for patterns, and the pattern.
#[derive(Clone, Debug)]
pub(crate) struct Fabric {
    pub base: Rgb,
    pub second: Rgb,
    pub pattern: Pattern,
    pub seed: u32,
}

impl Fabric {
    fn random(rng: &mut ChaCha8Rng, patterned: f64) -> Self {
        let base = palette::cloth(rng);
        let mut second = palette::cloth(rng);
        if (0..3).map(|k| (base[k] - second[k]).abs()).sum::<f32>() < 0.3 {
            second = if base.iter().sum::<f32>() > 1.5 {
                scale(base, 0.35)
            } else {
                mix(base, [1.0; 3], 0.7)
            };
        }
        let pattern = if rng.random_bool(patterned) {
            match rng.random_range(0..6) {
                0 | 1 => Pattern::HStripes {
                    period: rng.random_range(0.02..0.08),
                    duty: rng.random_range(0.3..0.6),
                },
                2 => Pattern::VStripes {
                    period: rng.random_range(0.015..0.05),
                    duty: rng.random_range(0.2..0.5),
                },
                3 => Pattern::Checks {
                    period: rng.random_range(0.025..0.07),
                },
                4 => Pattern::Plaid {
                    period: rng.random_range(0.05..0.12),
                },
                _ => Pattern::Dots {
                    period: rng.random_range(0.03..0.06),
                    radius: rng.random_range(0.2..0.35),
                },
            }
        } else if rng.random_bool(0.3) {
            Pattern::Knit
        } else {
            Pattern::Solid
        };
        Self {
            base,
            second,
            pattern,
            seed: rng.random(),
        }
    }

    fn denim(rng: &mut ChaCha8Rng) -> Self {
        let base = palette::denim(rng);
        Self {
            base,
            second: mix(base, [0.9, 0.92, 0.95], 0.35),
            pattern: Pattern::Denim,
            seed: rng.random(),
        }
    }

    /// The colour at garment coordinates `(u, v)` (metres around and along) and body point `p`.
    pub fn color(&self, u: f32, v: f32, p: Vec3) -> Rgb {
        // Anti-aliased square wave: 1 inside the first `duty` of each period, with edges
        // blurred over about the vertex spacing of the refined mesh.
        let band = |x: f32, period: f32, duty: f32| {
            let f = (x / period).rem_euclid(1.0) * period;
            let inside = 0.5 * duty * period - (f - 0.5 * duty * period).abs();
            let wrap = 0.5 * duty * period - (f - period - 0.5 * duty * period).abs();
            (inside.max(wrap) / 0.004 + 0.5).clamp(0.0, 1.0)
        };
        let n = fbm(p * 180.0, self.seed);
        let grain = 0.94 + 0.12 * n;
        match self.pattern {
            Pattern::Solid => scale(self.base, grain),
            Pattern::Knit => scale(
                self.base,
                0.9 + 0.2 * fbm(Vec3::new(u * 400.0, v * 250.0, 0.0), self.seed),
            ),
            Pattern::HStripes { period, duty } => {
                scale(mix(self.base, self.second, band(v, period, duty)), grain)
            }
            Pattern::VStripes { period, duty } => {
                scale(mix(self.base, self.second, band(u, period, duty)), grain)
            }
            Pattern::Checks { period } => {
                let a = ((u / period).floor() + (v / period).floor()).rem_euclid(2.0);
                scale(mix(self.base, self.second, a), grain)
            }
            Pattern::Plaid { period } => {
                let a = band(u, period, 0.3);
                let b = band(v, period, 0.3);
                let thin =
                    band(u + period * 0.5, period, 0.06).max(band(v + period * 0.5, period, 0.06));
                let c = mix(self.base, self.second, 0.5 * (a + b));
                scale(mix(c, scale(self.second, 0.5), 0.6 * thin), grain)
            }
            Pattern::Dots { period, radius } => {
                let fu = (u / period).rem_euclid(1.0) - 0.5;
                let fv = (v / period).rem_euclid(1.0) - 0.5;
                let d = (fu * fu + fv * fv).sqrt();
                let inside = ((radius - d) / 0.06 + 0.5).clamp(0.0, 1.0);
                scale(mix(self.base, self.second, inside), grain)
            }
            Pattern::Denim => {
                let twill = 0.5 + 0.5 * ((u + v) * 900.0).sin();
                let fade = fbm(p * 12.0, self.seed);
                let c = mix(self.base, self.second, 0.25 * fade + 0.15 * twill);
                scale(c, 0.92 + 0.16 * n)
            }
        }
    }
}

/// The upper garment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum TopKind {
    TShirt,
    LongSleeve,
    Tank,
    Sweater,
    Shirt,
}

/// The neckline of the upper garment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Neckline {
    Crew,
    V,
    Scoop,
    Turtle,
    Collar,
}

/// The lower garment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum BottomKind {
    Trousers,
    Jeans,
    Shorts,
    Skirt,
}

#[derive(Clone, Debug)]
pub(crate) struct Top {
    pub kind: TopKind,
    pub fabric: Fabric,
    /// Sleeve end along the arm (0 shoulder, 1 wrist).
    pub sleeve: f32,
    pub neckline: Neckline,
    /// How far the hem hangs below the waist (metres; 0 when tucked in).
    pub hem: f32,
    pub thickness: f32,
}

#[derive(Clone, Debug)]
pub(crate) struct Jacket {
    pub fabric: Fabric,
    /// Half-width of the open front.
    pub opening: f32,
    pub hem: f32,
    pub thickness: f32,
}

#[derive(Clone, Debug)]
pub(crate) struct Bottom {
    pub kind: BottomKind,
    pub fabric: Fabric,
    /// Length along the leg (0 hip, 1 ankle).
    pub length: f32,
    pub thickness: f32,
}

#[derive(Clone, Debug)]
pub(crate) struct Shoes {
    pub color: Rgb,
    pub sole: Rgb,
    /// Where the shoe starts along the leg (boots reach up the shin).
    pub top: f32,
}

/// Everything a person wears.
#[derive(Clone, Debug)]
pub(crate) struct Outfit {
    pub top: Top,
    pub jacket: Option<Jacket>,
    pub bottom: Bottom,
    /// A dress: the top's fabric continues into the skirt.
    pub dress: bool,
    pub shoes: Shoes,
    pub socks: Option<Rgb>,
    pub belt: Option<Rgb>,
}

impl Outfit {
    /// A random outfit; `feminine` makes skirts and dresses more likely.
    pub fn random(rng: &mut ChaCha8Rng, feminine: bool) -> Self {
        let dress = feminine && rng.random_bool(0.2);
        let kind = if dress {
            [TopKind::TShirt, TopKind::Tank, TopKind::LongSleeve][rng.random_range(0..3)]
        } else {
            [
                TopKind::TShirt,
                TopKind::TShirt,
                TopKind::LongSleeve,
                TopKind::Tank,
                TopKind::Sweater,
                TopKind::Shirt,
            ][rng.random_range(0..6)]
        };
        let sleeve = match kind {
            TopKind::TShirt => rng.random_range(0.22..0.42),
            TopKind::LongSleeve | TopKind::Sweater => rng.random_range(0.93..1.0),
            TopKind::Tank => 0.0,
            TopKind::Shirt => {
                if rng.random_bool(0.3) {
                    rng.random_range(0.55..0.7)
                } else {
                    0.97
                }
            }
        };
        let neckline = match kind {
            TopKind::Shirt => Neckline::Collar,
            TopKind::Sweater => {
                if rng.random_bool(0.3) {
                    Neckline::Turtle
                } else {
                    Neckline::Crew
                }
            }
            TopKind::Tank => {
                if rng.random_bool(0.5) {
                    Neckline::Scoop
                } else {
                    Neckline::Crew
                }
            }
            _ => [Neckline::Crew, Neckline::Crew, Neckline::V, Neckline::Scoop]
                [rng.random_range(0..4)],
        };
        let patterned = if kind == TopKind::Shirt { 0.6 } else { 0.35 };
        let top = Top {
            kind,
            fabric: Fabric::random(rng, patterned),
            sleeve,
            neckline,
            hem: if rng.random_bool(0.4) {
                0.0
            } else {
                rng.random_range(0.04..0.12)
            },
            thickness: if kind == TopKind::Sweater {
                0.011
            } else {
                rng.random_range(0.004..0.007)
            },
        };
        let jacket = (!dress && kind != TopKind::Tank && rng.random_bool(0.22)).then(|| Jacket {
            fabric: Fabric::random(rng, 0.15),
            opening: rng.random_range(0.03..0.07),
            hem: rng.random_range(0.08..0.16),
            thickness: rng.random_range(0.014..0.02),
        });
        let bottom_kind = if dress {
            BottomKind::Skirt
        } else {
            let skirt = if feminine { 0.3 } else { 0.0 };
            let r: f64 = rng.random_range(0.0..1.0);
            if r < skirt {
                BottomKind::Skirt
            } else if r < skirt + 0.35 {
                BottomKind::Jeans
            } else if r < skirt + 0.8 {
                BottomKind::Trousers
            } else {
                BottomKind::Shorts
            }
        };
        let mut top = top;
        if bottom_kind == BottomKind::Skirt {
            top.hem = 0.0; // tucked into the skirt
        }
        let bottom = Bottom {
            kind: bottom_kind,
            fabric: match bottom_kind {
                BottomKind::Jeans => Fabric::denim(rng),
                _ if dress => top.fabric.clone(),
                _ => Fabric::random(rng, 0.15),
            },
            length: match bottom_kind {
                BottomKind::Trousers | BottomKind::Jeans => rng.random_range(0.95..1.02),
                BottomKind::Shorts => rng.random_range(0.3..0.5),
                BottomKind::Skirt => rng.random_range(0.35..0.85),
            },
            thickness: match bottom_kind {
                BottomKind::Jeans => 0.008,
                _ => rng.random_range(0.005..0.01),
            },
        };
        let sneakers = rng.random_bool(0.5);
        let shoes = Shoes {
            color: if sneakers {
                palette::cloth(rng)
            } else {
                scale(palette::cloth(rng), 0.4)
            },
            sole: if sneakers {
                [0.92, 0.92, 0.9]
            } else {
                [0.1, 0.09, 0.08]
            },
            top: if !sneakers && rng.random_bool(0.25) {
                0.8
            } else {
                0.97
            },
        };
        let bare_shins = matches!(bottom_kind, BottomKind::Shorts | BottomKind::Skirt);
        let socks = (bare_shins && rng.random_bool(0.4)).then(|| {
            if rng.random_bool(0.5) {
                [0.95; 3]
            } else {
                palette::cloth(rng)
            }
        });
        let belt = (!dress && top.hem == 0.0 && rng.random_bool(0.6))
            .then(|| scale(palette::cloth(rng), 0.5));
        Self {
            top,
            jacket,
            bottom,
            dress,
            shoes,
            socks,
            belt,
        }
    }

    /// Whether the legs are bare under the bottom garment's end.
    pub fn skirt(&self) -> bool {
        self.bottom.kind == BottomKind::Skirt
    }
}

/// What covers a point of the body.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Cover {
    pub color: Rgb,
    pub offset: f32,
}

/// The clothes on a body point `p` (shaped rest frame) of region `region`, or `None` for skin.
pub(crate) fn clothe(outfit: &Outfit, lm: &Landmarks, region: Region, p: Vec3) -> Option<Cover> {
    let waist = lm.waist_y;
    let j = &lm.joints;
    let torso_uv = || {
        let a = p.x.atan2(p.z);
        (a * 0.16, p.y)
    };
    match region {
        Region::Torso | Region::Neck => {
            let (u, v) = torso_uv();
            let front = p.z > j[prism_body::joint::SPINE3].z;
            // Neckline: above it there is skin.
            let top = &outfit.top;
            let nb = lm.neck_base_y;
            let x = p.x.abs();
            let neck_line = match top.neckline {
                Neckline::Crew => {
                    nb - 0.012
                        - if front {
                            0.02 * (1.0 - (x / 0.07).min(1.0).powi(2))
                        } else {
                            0.0
                        }
                }
                Neckline::V => {
                    nb - 0.01
                        - if front {
                            (0.13 - 1.6 * x).max(0.0)
                        } else {
                            0.0
                        }
                }
                Neckline::Scoop => {
                    nb - 0.02
                        - if front {
                            0.08 * (1.0 - (x / 0.11).min(1.0).powi(2))
                        } else {
                            0.02
                        }
                }
                Neckline::Turtle => nb + 0.07,
                Neckline::Collar => {
                    nb + if front {
                        0.02 - (0.07 - 1.2 * x).max(0.0)
                    } else {
                        0.035
                    }
                }
            };
            let jacket_cover = outfit.jacket.as_ref().filter(|jk| {
                p.y >= waist - jk.hem
                    && p.y
                        <= nb
                            + if front {
                                -0.02 - (0.2 - 2.0 * x).max(0.0)
                            } else {
                                0.03
                            }
                    && !(front && x < jk.opening && p.y < nb - 0.02)
                    && region == Region::Torso
            });
            if let Some(jk) = jacket_cover {
                return Some(Cover {
                    color: jk.fabric.color(u, v, p),
                    offset: jk.thickness,
                });
            }
            let tank_strap =
                top.kind == TopKind::Tank && p.y > j[prism_body::joint::SPINE3].y + 0.04 && {
                    let strap = 0.085;
                    (x - strap).abs() > 0.022
                };
            let top_low = if outfit.dress {
                f32::NEG_INFINITY
            } else {
                waist - top.hem
            };
            if p.y >= top_low && p.y <= neck_line && !tank_strap {
                let mut c = top.fabric.color(u, v, p);
                if top.kind == TopKind::Shirt && front && x < 0.006 {
                    c = scale(c, 0.8); // button placket
                }
                if top.neckline == Neckline::Collar && p.y > nb - 0.03 {
                    c = scale(c, 1.05);
                }
                return Some(Cover {
                    color: c,
                    offset: top.thickness + if outfit.dress { 0.002 } else { 0.0 },
                });
            }
            if p.y < waist && region == Region::Torso {
                if let Some(belt) = outfit.belt.filter(|_| p.y > waist - 0.035) {
                    let buckle = front && x < 0.025;
                    let c = if buckle { [0.75, 0.7, 0.55] } else { belt };
                    return Some(Cover {
                        color: c,
                        offset: outfit.bottom.thickness + 0.003,
                    });
                }
                let b = &outfit.bottom;
                // Under a skirt the shell carries the volume.
                let offset = if b.kind == BottomKind::Skirt {
                    0.0
                } else {
                    b.thickness
                };
                return Some(Cover {
                    color: b.fabric.color(u, v, p),
                    offset,
                });
            }
            None
        }
        Region::Arm { left } => {
            let t = lm.arm_t(p, left);
            let axis = j[if left {
                prism_body::joint::LEFT_SHOULDER
            } else {
                prism_body::joint::RIGHT_SHOULDER
            }];
            let d = p - axis;
            let u = d.y.atan2(d.z) * 0.045;
            let v = p.x.abs();
            if let Some(jk) = outfit.jacket.as_ref().filter(|_| t < 0.97) {
                return Some(Cover {
                    color: jk.fabric.color(u, v, p),
                    offset: jk.thickness * 0.8,
                });
            }
            let top = &outfit.top;
            if t < top.sleeve || (top.kind != TopKind::Tank && t < 0.08) {
                let cuff =
                    if top.kind == TopKind::Shirt && t > top.sleeve - 0.04 && top.sleeve > 0.9 {
                        0.92
                    } else {
                        1.0
                    };
                return Some(Cover {
                    color: scale(top.fabric.color(u, v, p), cuff),
                    offset: top.thickness,
                });
            }
            None
        }
        Region::Leg { left } => {
            let t = lm.leg_t(p, left);
            let hip = j[if left {
                prism_body::joint::LEFT_HIP
            } else {
                prism_body::joint::RIGHT_HIP
            }];
            let d = p - hip;
            let u = d.x.atan2(d.z) * 0.07;
            if t > outfit.shoes.top {
                return Some(Cover {
                    color: outfit.shoes.color,
                    offset: 0.008,
                });
            }
            let b = &outfit.bottom;
            if b.kind != BottomKind::Skirt && t < b.length {
                let hem = if t > b.length - 0.02 && b.kind == BottomKind::Jeans {
                    0.85
                } else {
                    1.0
                };
                // Trouser legs hang straighter than the leg: looser towards the hem.
                let loose = match b.kind {
                    BottomKind::Trousers => 0.014,
                    BottomKind::Jeans => 0.006,
                    _ => 0.01,
                } * t.clamp(0.0, 1.0).sqrt();
                return Some(Cover {
                    color: scale(b.fabric.color(u, p.y, p), hem),
                    offset: b.thickness + loose,
                });
            }
            if let Some(s) = outfit.socks.filter(|_| t > 0.88) {
                return Some(Cover {
                    color: s,
                    offset: 0.002,
                });
            }
            // Short garments leave the upper thigh covered by the torso's garment under a skirt.
            if b.kind == BottomKind::Skirt && t < 0.12 {
                return Some(Cover {
                    color: b.fabric.color(u, p.y, p),
                    offset: 0.002,
                });
            }
            None
        }
        Region::Foot { .. } => {
            let sole = p.y < 0.014;
            let c = if sole {
                outfit.shoes.sole
            } else {
                outfit.shoes.color
            };
            let lace = !sole && p.y > 0.05 && p.x.abs() > 0.0 && {
                let ankle_z = j[prism_body::joint::LEFT_ANKLE].z;
                p.z > ankle_z + 0.02 && p.z < ankle_z + 0.1 && outfit.shoes.sole[0] > 0.5
            };
            Some(Cover {
                color: if lace { mix(c, [1.0; 3], 0.5) } else { c },
                offset: 0.009,
            })
        }
        Region::Head | Region::Eye { .. } | Region::Hand { .. } => None,
    }
}
