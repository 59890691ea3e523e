//! Colour spaces used for interpolating colour knots: RGB, HSV (HDR VolVis section 5), CIE
//! L*a*b* and Moreland's diverging Msh space (as ParaView / VTK's `vtkColorTransferFunction`
//! do, so that imported ParaView presets look the same).
//!
//! RGB triples are in [0, 1]. For the Lab and Msh spaces they are read as sRGB-encoded
//! colours (VTK's `vtkMath::RGBToLab` convention, D65 white (0.9505, 1.0, 1.089)).

use std::f64::consts::PI;

/// How colour is interpolated between two colour knots.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ColorSpace {
    /// Linear interpolation of the RGB components.
    #[default]
    Rgb,
    /// Interpolate hue, saturation and value, then convert to RGB (HDR VolVis section 5).
    /// Hue goes the short way round the hue circle (VTK's `HSVWrap`).
    Hsv,
    /// Linear interpolation in CIE L*a*b* (ParaView "Lab").
    Lab,
    /// Moreland's diverging interpolation in the polar Msh space, with white inserted
    /// between two distinct saturated hues (ParaView "Diverging"; Moreland 2009,
    /// "Diverging Color Maps for Scientific Visualization").
    Diverging,
    /// No interpolation: inside a segment the colour is that of the segment's right knot
    /// (ParaView "Step").
    Step,
}

impl ColorSpace {
    /// Interpolates between `a` (at s = 0) and `b` (at s = 1) in this space.
    #[must_use]
    /// At `s <= 0` it returns `a` and at `s >= 1` it returns `b` exactly.
    pub fn interpolate(self, a: [f64; 3], b: [f64; 3], s: f64) -> [f64; 3] {
        if s <= 0.0 {
            return a;
        }
        if s >= 1.0 {
            return b;
        }
        match self {
            ColorSpace::Rgb => lerp3(a, b, s),
            ColorSpace::Hsv => hsv_interpolate(a, b, s),
            ColorSpace::Lab => lab_to_rgb(lerp3(rgb_to_lab(a), rgb_to_lab(b), s)),
            ColorSpace::Diverging => diverging_interpolate(a, b, s),
            ColorSpace::Step => b,
        }
    }
}

fn lerp3(a: [f64; 3], b: [f64; 3], s: f64) -> [f64; 3] {
    [
        a[0] + (b[0] - a[0]) * s,
        a[1] + (b[1] - a[1]) * s,
        a[2] + (b[2] - a[2]) * s,
    ]
}

/// RGB in [0, 1] to HSV, all in [0, 1] (hue as a fraction of the full circle).
#[must_use]
pub fn rgb_to_hsv(rgb: [f64; 3]) -> [f64; 3] {
    let [r, g, b] = rgb;
    let max = r.max(g).max(b);
    let min = r.min(g).min(b);
    let v = max;
    let delta = max - min;
    let s = if max > 0.0 { delta / max } else { 0.0 };
    if delta <= 0.0 {
        return [0.0, s, v];
    }
    let mut h = if r == max {
        (g - b) / delta
    } else if g == max {
        2.0 + (b - r) / delta
    } else {
        4.0 + (r - g) / delta
    } / 6.0;
    if h < 0.0 {
        h += 1.0;
    }
    [h, s, v]
}

/// HSV (hue as a fraction of the circle; values outside [0, 1) wrap) to RGB.
#[must_use]
pub fn hsv_to_rgb(hsv: [f64; 3]) -> [f64; 3] {
    let [h, s, v] = hsv;
    let h6 = h.rem_euclid(1.0) * 6.0;
    let sector = h6.floor();
    let f = h6 - sector;
    let p = v * (1.0 - s);
    let q = v * (1.0 - s * f);
    let t = v * (1.0 - s * (1.0 - f));
    match sector as i32 {
        0 => [v, t, p],
        1 => [q, v, p],
        2 => [p, v, t],
        3 => [p, q, v],
        4 => [t, p, v],
        _ => [v, p, q],
    }
}

/// HSV interpolation along the shorter arc of the hue circle. A grey end (no saturation)
/// takes the hue of the other end, so grey-to-colour ramps do not sweep through hues.
#[must_use]
pub fn hsv_interpolate(a: [f64; 3], b: [f64; 3], s: f64) -> [f64; 3] {
    let mut ha = rgb_to_hsv(a);
    let mut hb = rgb_to_hsv(b);
    if ha[1] == 0.0 {
        ha[0] = hb[0];
    }
    if hb[1] == 0.0 {
        hb[0] = ha[0];
    }
    let mut dh = hb[0] - ha[0];
    if dh > 0.5 {
        dh -= 1.0;
    } else if dh < -0.5 {
        dh += 1.0;
    }
    let h = (ha[0] + dh * s).rem_euclid(1.0);
    hsv_to_rgb([
        h,
        ha[1] + (hb[1] - ha[1]) * s,
        ha[2] + (hb[2] - ha[2]) * s,
    ])
}

const WHITE_D65: [f64; 3] = [0.9505, 1.0, 1.089];

/// sRGB-encoded RGB in [0, 1] to CIE L*a*b* (VTK's `vtkMath::RGBToLab`).
#[must_use]
pub fn rgb_to_lab(rgb: [f64; 3]) -> [f64; 3] {
    let lin = |c: f64| {
        if c > 0.04045 {
            ((c + 0.055) / 1.055).powf(2.4)
        } else {
            c / 12.92
        }
    };
    let (r, g, b) = (lin(rgb[0]), lin(rgb[1]), lin(rgb[2]));
    let x = r * 0.4124 + g * 0.3576 + b * 0.1805;
    let y = r * 0.2126 + g * 0.7152 + b * 0.0722;
    let z = r * 0.0193 + g * 0.1192 + b * 0.9505;
    let f = |t: f64| {
        if t > 0.008856 {
            t.cbrt()
        } else {
            7.787 * t + 16.0 / 116.0
        }
    };
    let fx = f(x / WHITE_D65[0]);
    let fy = f(y / WHITE_D65[1]);
    let fz = f(z / WHITE_D65[2]);
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// CIE L*a*b* to sRGB-encoded RGB, clipped into [0, 1] like VTK's `vtkMath::LabToRGB`
/// (scaled down by the largest component if it exceeds 1, negatives set to 0).
#[must_use]
pub fn lab_to_rgb(lab: [f64; 3]) -> [f64; 3] {
    let fy = (lab[0] + 16.0) / 116.0;
    let fx = lab[1] / 500.0 + fy;
    let fz = fy - lab[2] / 200.0;
    let finv = |t: f64| {
        let t3 = t * t * t;
        if t3 > 0.008856 {
            t3
        } else {
            (t - 16.0 / 116.0) / 7.787
        }
    };
    let x = finv(fx) * WHITE_D65[0];
    let y = finv(fy) * WHITE_D65[1];
    let z = finv(fz) * WHITE_D65[2];
    let r = x * 3.2406 + y * -1.5372 + z * -0.4986;
    let g = x * -0.9689 + y * 1.8758 + z * 0.0415;
    let b = x * 0.0557 + y * -0.2040 + z * 1.0570;
    let enc = |c: f64| {
        if c > 0.0031308 {
            1.055 * c.powf(1.0 / 2.4) - 0.055
        } else {
            12.92 * c
        }
    };
    let mut out = [enc(r), enc(g), enc(b)];
    let max = out[0].max(out[1]).max(out[2]);
    if max > 1.0 {
        for c in &mut out {
            *c /= max;
        }
    }
    for c in &mut out {
        if *c < 0.0 {
            *c = 0.0;
        }
    }
    out
}

fn lab_to_msh(lab: [f64; 3]) -> [f64; 3] {
    let [l, a, b] = lab;
    let m = (l * l + a * a + b * b).sqrt();
    let s = if m > 0.001 { (l / m).acos() } else { 0.0 };
    let h = if s > 0.001 { b.atan2(a) } else { 0.0 };
    [m, s, h]
}

fn msh_to_lab(msh: [f64; 3]) -> [f64; 3] {
    let [m, s, h] = msh;
    [m * s.cos(), m * s.sin() * h.cos(), m * s.sin() * h.sin()]
}

fn angle_diff(a1: f64, a2: f64) -> f64 {
    let mut d = (a1 - a2).abs();
    while d >= 2.0 * PI {
        d -= 2.0 * PI;
    }
    if d > PI { 2.0 * PI - d } else { d }
}

fn adjust_hue(msh: [f64; 3], unsat_m: f64) -> f64 {
    if msh[0] >= unsat_m - 0.1 {
        msh[2]
    } else {
        let spin = msh[1] * (unsat_m * unsat_m - msh[0] * msh[0]).sqrt() / (msh[0] * msh[1].sin());
        if msh[2] > -0.3 * PI {
            msh[2] + spin
        } else {
            msh[2] - spin
        }
    }
}

/// Moreland's diverging interpolation (the algorithm of VTK's
/// `vtkColorTransferFunctionInterpolateDiverging`).
#[must_use]
pub fn diverging_interpolate(a: [f64; 3], b: [f64; 3], s: f64) -> [f64; 3] {
    let mut m1 = lab_to_msh(rgb_to_lab(a));
    let mut m2 = lab_to_msh(rgb_to_lab(b));
    let mut s = s;
    if m1[1] > 0.05 && m2[1] > 0.05 && angle_diff(m1[2], m2[2]) > 0.33 * PI {
        let mid = m1[0].max(m2[0]).max(88.0);
        if s < 0.5 {
            m2 = [mid, 0.0, 0.0];
            s *= 2.0;
        } else {
            m1 = [mid, 0.0, 0.0];
            s = 2.0 * s - 1.0;
        }
    }
    if m1[1] < 0.05 && m2[1] > 0.05 {
        m1[2] = adjust_hue(m2, m1[0]);
    } else if m2[1] < 0.05 && m1[1] > 0.05 {
        m2[2] = adjust_hue(m1, m2[0]);
    }
    lab_to_rgb(msh_to_lab(lerp3(m1, m2, s)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hsv_round_trips_primary_and_mixed_colours() {
        for rgb in [
            [1.0, 0.0, 0.0],
            [0.2, 0.7, 0.3],
            [0.9, 0.1, 0.8],
            [0.5, 0.5, 0.5],
            [0.0, 0.0, 0.0],
        ] {
            let back = hsv_to_rgb(rgb_to_hsv(rgb));
            for c in 0..3 {
                assert!((back[c] - rgb[c]).abs() < 1e-12, "{rgb:?} -> {back:?}");
            }
        }
    }

    #[test]
    fn lab_of_white_is_l100_and_round_trips() {
        let lab = rgb_to_lab([1.0, 1.0, 1.0]);
        assert!((lab[0] - 100.0).abs() < 0.01, "{lab:?}");
        assert!(lab[1].abs() < 0.05 && lab[2].abs() < 0.05, "{lab:?}");
        let rgb = [0.3, 0.6, 0.2];
        let back = lab_to_rgb(rgb_to_lab(rgb));
        for c in 0..3 {
            assert!((back[c] - rgb[c]).abs() < 1e-3, "{back:?}");
        }
    }
}
