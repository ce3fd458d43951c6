//! Colours of skin, hair, eyes and clothes (display values in [0, 1]).

use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Colour as RGB in [0, 1].
pub(crate) type Rgb = [f32; 3];

/// Skin tones from very light to very dark.
const SKIN: [Rgb; 9] = [
    [0.96, 0.82, 0.72],
    [0.93, 0.76, 0.64],
    [0.88, 0.69, 0.56],
    [0.80, 0.60, 0.46],
    [0.72, 0.52, 0.38],
    [0.60, 0.42, 0.30],
    [0.47, 0.32, 0.22],
    [0.36, 0.24, 0.17],
    [0.26, 0.17, 0.12],
];

/// Natural hair colours (black to blonde, red, grey) and a few dyed ones.
const HAIR: [Rgb; 10] = [
    [0.05, 0.04, 0.04],
    [0.12, 0.08, 0.06],
    [0.22, 0.14, 0.09],
    [0.36, 0.24, 0.15],
    [0.55, 0.40, 0.24],
    [0.78, 0.64, 0.40],
    [0.48, 0.20, 0.09],
    [0.55, 0.55, 0.55],
    [0.82, 0.82, 0.80],
    [0.45, 0.20, 0.45],
];

/// Iris colours: dark brown, brown, hazel, green, blue, grey.
const IRIS: [Rgb; 6] = [
    [0.16, 0.09, 0.05],
    [0.30, 0.18, 0.09],
    [0.42, 0.33, 0.16],
    [0.28, 0.40, 0.25],
    [0.28, 0.42, 0.62],
    [0.45, 0.50, 0.55],
];

/// Clothing colours: neutrals, darks, brights, pastels.
const CLOTH: [Rgb; 24] = [
    [0.08, 0.08, 0.09],
    [0.93, 0.93, 0.92],
    [0.55, 0.56, 0.58],
    [0.30, 0.31, 0.33],
    [0.10, 0.14, 0.30],
    [0.20, 0.32, 0.60],
    [0.52, 0.68, 0.85],
    [0.60, 0.10, 0.12],
    [0.82, 0.18, 0.16],
    [0.93, 0.55, 0.20],
    [0.95, 0.82, 0.30],
    [0.30, 0.45, 0.22],
    [0.30, 0.35, 0.20],
    [0.15, 0.45, 0.42],
    [0.45, 0.25, 0.50],
    [0.90, 0.62, 0.70],
    [0.80, 0.72, 0.58],
    [0.55, 0.40, 0.26],
    [0.35, 0.22, 0.14],
    [0.70, 0.80, 0.65],
    [0.98, 0.96, 0.88],
    [0.25, 0.18, 0.35],
    [0.85, 0.40, 0.45],
    [0.40, 0.60, 0.75],
];

/// Denim blues.
const DENIM: [Rgb; 4] = [
    [0.16, 0.24, 0.40],
    [0.25, 0.36, 0.55],
    [0.42, 0.52, 0.66],
    [0.12, 0.13, 0.17],
];

fn jitter(rng: &mut ChaCha8Rng, c: Rgb, amount: f32) -> Rgb {
    let k = 1.0 + rng.random_range(-amount..=amount);
    c.map(|x| (x * k + rng.random_range(-amount..=amount) * 0.3).clamp(0.0, 1.0))
}

fn pick(rng: &mut ChaCha8Rng, list: &[Rgb]) -> Rgb {
    list[rng.random_range(0..list.len())]
}

/// A skin tone: between two neighbouring tones of the scale, slightly varied.
pub(crate) fn skin(rng: &mut ChaCha8Rng) -> Rgb {
    let i = rng.random_range(0..SKIN.len() - 1);
    let t: f32 = rng.random_range(0.0..1.0);
    let c = std::array::from_fn(|k| SKIN[i][k] + (SKIN[i + 1][k] - SKIN[i][k]) * t);
    jitter(rng, c, 0.03)
}

/// A hair colour (dyed colours are rare).
pub(crate) fn hair(rng: &mut ChaCha8Rng) -> Rgb {
    let c = if rng.random_bool(0.05) {
        HAIR[HAIR.len() - 1]
    } else {
        HAIR[rng.random_range(0..HAIR.len() - 1)]
    };
    jitter(rng, c, 0.06)
}

/// An iris colour.
pub(crate) fn iris(rng: &mut ChaCha8Rng) -> Rgb {
    let c = pick(rng, &IRIS);
    jitter(rng, c, 0.05)
}

/// A clothing colour.
pub(crate) fn cloth(rng: &mut ChaCha8Rng) -> Rgb {
    let c = pick(rng, &CLOTH);
    jitter(rng, c, 0.08)
}

/// A denim colour.
pub(crate) fn denim(rng: &mut ChaCha8Rng) -> Rgb {
    let c = pick(rng, &DENIM);
    jitter(rng, c, 0.05)
}

/// Mixes `a` towards `b` by `t`.
pub(crate) fn mix(a: Rgb, b: Rgb, t: f32) -> Rgb {
    std::array::from_fn(|k| a[k] + (b[k] - a[k]) * t)
}

/// Scales a colour.
pub(crate) fn scale(a: Rgb, k: f32) -> Rgb {
    a.map(|x| (x * k).clamp(0.0, 1.0))
}
