//! The transfer function itself: colour knots, opacity knots, global opacity alpha_g, a data
//! domain and an optional logarithmic data axis.

use std::ops::RangeInclusive;

use crate::color::ColorSpace;
use crate::{Error, Result};

/// A colour knot: at data value `x` the colour is `rgb`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ColorKnot {
    /// Position, in data units (the same units as the volume's scalar).
    pub x: f64,
    /// Linear interpolation weights' end point, each component in [0, 1]. For the renderer
    /// this is the emissive colour (MDWT section 4.3: "We interpret the linear RGB returned
    /// from TF as an emissive color").
    pub rgb: [f32; 3],
}

/// An opacity knot: at data value `x` the opacity is `alpha`.
///
/// `midpoint` and `sharpness` shape the segment from this knot to the next one exactly as
/// in VTK's `vtkPiecewiseFunction` (ParaView's opacity `Points` are quadruples `x, alpha,
/// midpoint, sharpness`). The defaults 0.5 and 0.0 give a straight line.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct OpacityKnot {
    /// Position, in data units.
    pub x: f64,
    /// Opacity in [0, 1], before the global opacity alpha_g is applied.
    pub alpha: f32,
    /// Where, as a fraction of the segment to the next knot, the curve reaches the mean of
    /// the two opacities; in [0, 1], default 0.5.
    #[serde(default = "default_midpoint")]
    pub midpoint: f32,
    /// 0 = linear, 1 = step at the midpoint, in between a Hermite curve; in [0, 1].
    #[serde(default)]
    pub sharpness: f32,
}

fn default_midpoint() -> f32 {
    0.5
}

impl OpacityKnot {
    /// A knot with a straight segment to the next knot (midpoint 0.5, sharpness 0).
    #[must_use]
    pub fn new(x: f64, alpha: f32) -> Self {
        Self {
            x,
            alpha,
            midpoint: 0.5,
            sharpness: 0.0,
        }
    }
}

/// How the data axis is parameterised between knots.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DataAxis {
    /// Knots are interpolated linearly in the data value.
    #[default]
    Linear,
    /// Knots are interpolated linearly in log10 of the data value, for positive
    /// heavy-tailed data (ParaView's `UseLogScale`). The domain and every knot must be > 0.
    Log,
}

impl DataAxis {
    /// The interpolation coordinate of a data value (the value itself or its log10).
    #[inline]
    #[must_use]
    pub fn coord(self, value: f64) -> f64 {
        match self {
            DataAxis::Linear => value,
            DataAxis::Log => value.log10(),
        }
    }

    /// Inverse of [`DataAxis::coord`].
    #[inline]
    #[must_use]
    pub fn value(self, coord: f64) -> f64 {
        match self {
            DataAxis::Linear => coord,
            DataAxis::Log => 10f64.powf(coord),
        }
    }
}

/// A 1D transfer function over a data domain `[min, max]`.
///
/// # What opacity means
/// [`TransferFunction::eval`] returns RGBA where A is the knot opacity times the global
/// opacity alpha_g (HDR VolVis section 3), a number in [0, 1] with no unit. blueshift's
/// renderers multiply it by a density scale (per metre, or per voxel length) to obtain the
/// extinction coefficient sigma_t per unit length; it is not a per-sample compositing alpha,
/// so it does not depend on the step size. [`TransferFunction::max_opacity`] bounds it over
/// a scalar interval for majorants (MDWT section 4.3).
///
/// Values outside the domain are clamped to it; beyond the first or last knot the knot's
/// value is held. NaN data maps to the NaN colour with opacity 0.
///
/// The invariants (non-empty sorted knots, opacities in [0, 1], a non-degenerate finite
/// domain, positivity on a log axis) are checked by the constructors, so every
/// `TransferFunction` can be evaluated without further checks.
#[derive(Clone, Debug, PartialEq)]
pub struct TransferFunction {
    name: String,
    domain: [f64; 2],
    data_axis: DataAxis,
    color_space: ColorSpace,
    color: Vec<ColorKnot>,
    color_u: Vec<f64>,
    opacity: Vec<OpacityKnot>,
    opacity_u: Vec<f64>,
    alpha_g: f32,
    nan_color: [f32; 3],
}

fn check_unit(what: &str, v: f32) -> Result<()> {
    if !(0.0..=1.0).contains(&v) {
        return Err(Error::invalid(format!("{what} is {v}, outside [0, 1]")));
    }
    Ok(())
}

impl TransferFunction {
    /// Builds a transfer function with RGB interpolation, a linear data axis, alpha_g = 1
    /// and a grey NaN colour. Knots must be sorted by `x` (equal positions are allowed and
    /// make a jump), colours and opacities in [0, 1], everything finite.
    pub fn new(domain: [f64; 2], color: Vec<ColorKnot>, opacity: Vec<OpacityKnot>) -> Result<Self> {
        let mut tf = Self {
            name: String::new(),
            domain,
            data_axis: DataAxis::Linear,
            color_space: ColorSpace::Rgb,
            color,
            color_u: Vec::new(),
            opacity,
            opacity_u: Vec::new(),
            alpha_g: 1.0,
            nan_color: [0.5, 0.5, 0.5],
        };
        tf.validate()?;
        Ok(tf)
    }

    /// Sets the colour interpolation space (HSV in HDR VolVis section 5).
    #[must_use]
    pub fn with_color_space(mut self, space: ColorSpace) -> Self {
        self.color_space = space;
        self
    }

    /// Sets the data axis; a log axis needs a positive domain and positive knots.
    pub fn with_data_axis(mut self, axis: DataAxis) -> Result<Self> {
        self.data_axis = axis;
        self.validate()?;
        Ok(self)
    }

    /// Sets the global opacity alpha_g in [0, 1] (HDR VolVis section 3), which multiplies
    /// every opacity.
    pub fn with_alpha_g(mut self, alpha_g: f32) -> Result<Self> {
        check_unit("alpha_g", alpha_g)?;
        self.alpha_g = alpha_g;
        Ok(self)
    }

    /// Sets the name (kept in JSON and ParaView files).
    #[must_use]
    pub fn with_name(mut self, name: impl Into<String>) -> Self {
        self.name = name.into();
        self
    }

    /// Sets the colour returned for NaN data (components in [0, 1]).
    pub fn with_nan_color(mut self, rgb: [f32; 3]) -> Result<Self> {
        for (c, v) in rgb.iter().enumerate() {
            check_unit(&format!("NaN colour component {c}"), *v)?;
        }
        self.nan_color = rgb;
        Ok(self)
    }

    /// Changes the domain (data units); knots keep their data positions.
    pub fn with_domain(mut self, domain: [f64; 2]) -> Result<Self> {
        self.domain = domain;
        self.validate()?;
        Ok(self)
    }

    /// The same map stretched over a new domain, ParaView's "rescale to data range": every
    /// knot keeps its relative position in the domain, measured on the data axis (linear, or
    /// log10 on a logarithmic axis, where the new domain must be positive). Compare
    /// [`TransferFunction::with_domain`], which keeps the knots where they are.
    pub fn rescaled(&self, domain: [f64; 2]) -> Result<Self> {
        let [lo, hi] = domain;
        if !(lo.is_finite() && hi.is_finite()) || lo >= hi {
            return Err(Error::invalid(format!(
                "domain [{lo}, {hi}] must be finite with min < max"
            )));
        }
        let axis = self.data_axis;
        if axis == DataAxis::Log && lo <= 0.0 {
            return Err(Error::invalid(format!(
                "a logarithmic data axis needs a positive domain, got [{lo}, {hi}]"
            )));
        }
        let (u0, u1) = (axis.coord(self.domain[0]), axis.coord(self.domain[1]));
        let (v0, v1) = (axis.coord(lo), axis.coord(hi));
        // Old domain ends map exactly onto the new ones; a knot outside the old domain keeps
        // its relative distance.
        let map = |x: f64| {
            if x == self.domain[0] {
                return lo;
            }
            if x == self.domain[1] {
                return hi;
            }
            let t = (axis.coord(x) - u0) / (u1 - u0);
            axis.value(v0 + t * (v1 - v0))
        };
        let mut tf = self.clone();
        tf.domain = domain;
        for k in &mut tf.color {
            k.x = map(k.x);
        }
        for k in &mut tf.opacity {
            k.x = map(k.x);
        }
        tf.validate()?;
        Ok(tf)
    }

    fn validate(&mut self) -> Result<()> {
        let [lo, hi] = self.domain;
        if !(lo.is_finite() && hi.is_finite()) || lo >= hi {
            return Err(Error::invalid(format!(
                "domain [{lo}, {hi}] must be finite with min < max"
            )));
        }
        // Its width divides every lookup: neither infinite ([-1e308, 1e308]) nor subnormal.
        if !(hi - lo).is_normal() {
            return Err(Error::invalid(format!(
                "domain [{lo}, {hi}]: its width {} is not a normal finite number",
                hi - lo
            )));
        }
        let log = self.data_axis == DataAxis::Log;
        if log && lo <= 0.0 {
            return Err(Error::invalid(format!(
                "a logarithmic data axis needs a positive domain, got [{lo}, {hi}]"
            )));
        }
        if self.color.is_empty() {
            return Err(Error::invalid("there are no colour knots"));
        }
        if self.opacity.is_empty() {
            return Err(Error::invalid("there are no opacity knots"));
        }
        let check_x = |kind: &str, i: usize, x: f64, prev: Option<f64>| -> Result<()> {
            if !x.is_finite() {
                return Err(Error::invalid(format!(
                    "{kind} knot {i}: position {x} is not finite"
                )));
            }
            if log && x <= 0.0 {
                return Err(Error::invalid(format!(
                    "{kind} knot {i}: position {x} is not positive, as a logarithmic data axis needs"
                )));
            }
            if let Some(p) = prev
                && x < p
            {
                return Err(Error::invalid(format!(
                    "{kind} knot {i}: position {x} comes after {p}; knots must be sorted by position"
                )));
            }
            Ok(())
        };
        for (i, k) in self.color.iter().enumerate() {
            check_x("colour", i, k.x, i.checked_sub(1).map(|j| self.color[j].x))?;
            for (c, v) in k.rgb.iter().enumerate() {
                if !(0.0..=1.0).contains(v) {
                    return Err(Error::invalid(format!(
                        "colour knot {i} (x = {}): component {c} is {v}, outside [0, 1]",
                        k.x
                    )));
                }
            }
        }
        for (i, k) in self.opacity.iter().enumerate() {
            check_x(
                "opacity",
                i,
                k.x,
                i.checked_sub(1).map(|j| self.opacity[j].x),
            )?;
            for (what, v) in [
                ("opacity", k.alpha),
                ("midpoint", k.midpoint),
                ("sharpness", k.sharpness),
            ] {
                if !(0.0..=1.0).contains(&v) {
                    return Err(Error::invalid(format!(
                        "opacity knot {i} (x = {}): {what} {v} is outside [0, 1]",
                        k.x
                    )));
                }
            }
        }
        check_unit("alpha_g", self.alpha_g)?;
        let axis = self.data_axis;
        self.color_u = self.color.iter().map(|k| axis.coord(k.x)).collect();
        self.opacity_u = self.opacity.iter().map(|k| axis.coord(k.x)).collect();
        Ok(())
    }

    /// The name ("" if none).
    #[must_use]
    pub fn name(&self) -> &str {
        &self.name
    }
    /// The data domain `[min, max]`, in data units.
    #[must_use]
    pub fn domain(&self) -> [f64; 2] {
        self.domain
    }
    /// The data axis (linear or log).
    #[must_use]
    pub fn data_axis(&self) -> DataAxis {
        self.data_axis
    }
    /// The colour interpolation space.
    #[must_use]
    pub fn color_space(&self) -> ColorSpace {
        self.color_space
    }
    /// The colour knots, sorted by position.
    #[must_use]
    pub fn color_knots(&self) -> &[ColorKnot] {
        &self.color
    }
    /// The opacity knots, sorted by position (opacities before alpha_g).
    #[must_use]
    pub fn opacity_knots(&self) -> &[OpacityKnot] {
        &self.opacity
    }
    /// The global opacity alpha_g.
    #[must_use]
    pub fn alpha_g(&self) -> f32 {
        self.alpha_g
    }
    /// The colour of NaN data.
    #[must_use]
    pub fn nan_color(&self) -> [f32; 3] {
        self.nan_color
    }

    /// Position of `value` along the (linear or log) data axis, 0 at `min` and 1 at `max`,
    /// clamped to [0, 1]. This is the "normalised intensity" of HDR VolVis Eq. 2.
    #[must_use]
    pub fn normalized(&self, value: f64) -> f64 {
        let [lo, hi] = self.domain;
        let a = self.data_axis.coord(lo);
        let b = self.data_axis.coord(hi);
        ((self.data_axis.coord(value.clamp(lo, hi)) - a) / (b - a)).clamp(0.0, 1.0)
    }

    /// Inverse of [`TransferFunction::normalized`]: the data value at normalised position `t`.
    #[must_use]
    pub fn value_at_normalized(&self, t: f64) -> f64 {
        let [lo, hi] = self.domain;
        let a = self.data_axis.coord(lo);
        let b = self.data_axis.coord(hi);
        self.data_axis
            .value(a + (b - a) * t.clamp(0.0, 1.0))
            .clamp(lo, hi)
    }

    #[inline]
    fn coord_clamped(&self, value: f64) -> f64 {
        self.data_axis
            .coord(value.clamp(self.domain[0], self.domain[1]))
    }

    /// Evaluates RGBA at a data value: colour interpolated in the chosen space, opacity
    /// times alpha_g. NaN gives the NaN colour with opacity 0.
    #[must_use]
    pub fn eval(&self, value: f64) -> [f32; 4] {
        if value.is_nan() {
            let [r, g, b] = self.nan_color;
            return [r, g, b, 0.0];
        }
        let u = self.coord_clamped(value);
        let [r, g, b] = self.color_at(u);
        [r, g, b, self.scaled(self.opacity_raw(u))]
    }

    /// The opacity (times alpha_g) at a data value; 0 for NaN.
    #[must_use]
    pub fn opacity(&self, value: f64) -> f32 {
        if value.is_nan() {
            return 0.0;
        }
        self.scaled(self.opacity_raw(self.coord_clamped(value)))
    }

    /// The colour at a data value (the NaN colour for NaN).
    #[must_use]
    pub fn color(&self, value: f64) -> [f32; 3] {
        if value.is_nan() {
            return self.nan_color;
        }
        self.color_at(self.coord_clamped(value))
    }

    /// The knot opacity at a data value, before alpha_g.
    #[must_use]
    pub fn base_opacity(&self, value: f64) -> f32 {
        if value.is_nan() {
            return 0.0;
        }
        self.opacity_raw(self.coord_clamped(value)) as f32
    }

    #[inline]
    fn scaled(&self, raw: f64) -> f32 {
        (raw * f64::from(self.alpha_g)) as f32
    }

    fn color_at(&self, u: f64) -> [f32; 3] {
        self.color_in_segment(self.color_u.partition_point(|&k| k <= u), u)
    }

    /// Colour at axis coordinate `u`, given `i`, the number of colour knots at or before `u`.
    #[inline]
    fn color_in_segment(&self, i: usize, u: f64) -> [f32; 3] {
        let ku = &self.color_u;
        let f = |k: &ColorKnot| k.rgb.map(f64::from);
        let rgb = if i == 0 {
            f(&self.color[0])
        } else if i == ku.len() {
            f(&self.color[ku.len() - 1])
        } else {
            let s = (u - ku[i - 1]) / (ku[i] - ku[i - 1]);
            self.color_space
                .interpolate(f(&self.color[i - 1]), f(&self.color[i]), s)
        };
        rgb.map(|c| c.clamp(0.0, 1.0) as f32)
    }

    /// Evaluates at increasing data values, writing RGBA into `out` (4 numbers per value).
    /// Walks the knots instead of searching them; the result is bit for bit that of
    /// [`TransferFunction::eval`].
    pub(crate) fn eval_increasing(&self, values: impl Iterator<Item = f64>, out: &mut [f32]) {
        let (mut ci, mut oi) = (usize::MAX, usize::MAX);
        let advance = |ku: &[f64], i: &mut usize, u: f64| {
            if *i == usize::MAX || (*i > 0 && ku[*i - 1] > u) {
                *i = ku.partition_point(|&k| k <= u);
            } else {
                while *i < ku.len() && ku[*i] <= u {
                    *i += 1;
                }
            }
        };
        for (v, px) in values.zip(out.chunks_exact_mut(4)) {
            if v.is_nan() {
                px.copy_from_slice(&self.eval(v));
                continue;
            }
            let u = self.coord_clamped(v);
            advance(&self.color_u, &mut ci, u);
            advance(&self.opacity_u, &mut oi, u);
            let [r, g, b] = self.color_in_segment(ci, u);
            px.copy_from_slice(&[r, g, b, self.scaled(self.opacity_in_segment(oi, u))]);
        }
    }

    /// Knot opacity at axis coordinate `u`, before alpha_g. Within a segment it is
    /// monotonic in `u` (also in floating point for straight segments, see `max_opacity`).
    fn opacity_raw(&self, u: f64) -> f64 {
        self.opacity_in_segment(self.opacity_u.partition_point(|&k| k <= u), u)
    }

    /// Knot opacity at `u`, given `i`, the number of opacity knots at or before `u`.
    #[inline]
    fn opacity_in_segment(&self, i: usize, u: f64) -> f64 {
        let ku = &self.opacity_u;
        if i == 0 {
            return f64::from(self.opacity[0].alpha);
        }
        if i == ku.len() {
            return f64::from(self.opacity[ku.len() - 1].alpha);
        }
        let k1 = &self.opacity[i - 1];
        let k2 = &self.opacity[i];
        let t = (u - ku[i - 1]) / (ku[i] - ku[i - 1]);
        segment_value(
            f64::from(k1.alpha),
            f64::from(k2.alpha),
            t,
            f64::from(k1.midpoint),
            f64::from(k1.sharpness),
        )
    }

    /// The largest opacity (times alpha_g) that [`TransferFunction::eval`] returns for any
    /// data value in `range`: the majorant query of MDWT section 4.3, done exactly with
    /// respect to the knots instead of by sampling.
    ///
    /// It never underestimates: the result is `>=` `eval(v)[3]` for every `v` in the range,
    /// bit for bit. For straight segments (sharpness < 0.01) it is exact, the maximum of the
    /// function at the interval's ends and at the knots inside; a curved ParaView segment
    /// (0.01 <= sharpness <= 0.99) that the interval enters contributes the larger of its two
    /// knot opacities. A range with NaN gives the global maximum; reversed ends are swapped.
    #[must_use]
    pub fn max_opacity(&self, range: RangeInclusive<f64>) -> f32 {
        let (mut lo, mut hi) = range.into_inner();
        if lo.is_nan() || hi.is_nan() {
            return self.global_max_opacity();
        }
        if lo > hi {
            std::mem::swap(&mut lo, &mut hi);
        }
        let mut ulo = self.coord_clamped(lo);
        let mut uhi = self.coord_clamped(hi);
        if self.data_axis == DataAxis::Log {
            // log10 is not guaranteed to be monotonic to the last bit: widen by one ulp so
            // that every coordinate eval() can produce for this range lies inside.
            ulo = ulo.next_down();
            uhi = uhi.next_up();
        }
        let mut m = self.opacity_raw(ulo).max(self.opacity_raw(uhi));
        let ku = &self.opacity_u;
        let first = ku.partition_point(|&k| k < ulo);
        let mut i = first;
        while i < ku.len() && ku[i] <= uhi {
            m = m.max(f64::from(self.opacity[i].alpha));
            i += 1;
        }
        // Curved segments are not monotonic in floating point: bound them by their knots.
        // Segment j spans knots j..j+1; the interval meets its interior when it overlaps.
        let seg_lo = first.saturating_sub(1);
        let seg_hi = i.min(ku.len().saturating_sub(1));
        for j in seg_lo..seg_hi {
            let k = &self.opacity[j];
            if is_curved(f64::from(k.sharpness)) && ku[j] < uhi && ku[j + 1] > ulo {
                m = m
                    .max(f64::from(k.alpha))
                    .max(f64::from(self.opacity[j + 1].alpha));
            }
        }
        self.scaled(m)
    }

    /// The largest opacity (times alpha_g) over the whole domain.
    #[must_use]
    pub fn global_max_opacity(&self) -> f32 {
        let m = self
            .opacity
            .iter()
            .map(|k| f64::from(k.alpha))
            .fold(0.0, f64::max);
        self.scaled(m)
    }
}

#[inline]
fn is_curved(sharpness: f64) -> bool {
    (0.01..=0.99).contains(&sharpness)
}

/// One segment of VTK's piecewise function (`vtkPiecewiseFunction::GetTable`), `t` in
/// [0, 1) the position inside the segment. Straight segments are computed as
/// `y1 + (y2 - y1) * t`, whose correctly rounded operations are each monotonic, so the
/// result is monotonic in `t` in floating point too.
fn segment_value(y1: f64, y2: f64, t: f64, midpoint: f64, sharpness: f64) -> f64 {
    // Readjust based on the midpoint (VTK: a linear adjustment).
    let x = if t < midpoint {
        0.5 * t / midpoint
    } else {
        0.5 + 0.5 * (t - midpoint) / (1.0 - midpoint).max(f64::MIN_POSITIVE)
    };
    if sharpness > 0.99 {
        return if x < 0.5 { y1 } else { y2 };
    }
    let (lo, hi) = if y1 < y2 { (y1, y2) } else { (y2, y1) };
    if sharpness < 0.01 {
        return (y1 + (y2 - y1) * x).clamp(lo, hi);
    }
    // Modified Hermite curve, as VTK: sharpen the position, then use one slope at both ends.
    let x = if x < 0.5 {
        0.5 * (x * 2.0).powf(1.0 + sharpness * 10.0)
    } else if x > 0.5 {
        1.0 - 0.5 * ((1.0 - x) * 2.0).powf(1.0 + sharpness * 10.0)
    } else {
        x
    };
    let ss = x * x;
    let sss = ss * x;
    let h1 = 2.0 * sss - 3.0 * ss + 1.0;
    let h2 = -2.0 * sss + 3.0 * ss;
    let h3 = sss - 2.0 * ss + x;
    let h4 = sss - ss;
    let slope = (1.0 - sharpness) * (y2 - y1);
    (h1 * y1 + h2 * y2 + h3 * slope + h4 * slope).clamp(lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp() -> TransferFunction {
        TransferFunction::new(
            [0.0, 10.0],
            vec![
                ColorKnot {
                    x: 0.0,
                    rgb: [0.0, 0.0, 0.0],
                },
                ColorKnot {
                    x: 10.0,
                    rgb: [1.0, 1.0, 1.0],
                },
            ],
            vec![
                OpacityKnot::new(0.0, 0.0),
                OpacityKnot::new(4.0, 0.8),
                OpacityKnot::new(6.0, 0.2),
                OpacityKnot::new(10.0, 0.4),
            ],
        )
        .unwrap()
    }

    #[test]
    fn rescaled_keeps_each_knot_at_its_relative_position() {
        // ParaView's "rescale to data range": [0, 10] stretched to [100, 4100] puts the knot
        // at 4 (40 %) at 1700 and evaluates there as the original did at 4.
        let tf = ramp();
        let r = tf.rescaled([100.0, 4100.0]).unwrap();
        assert_eq!(r.domain(), [100.0, 4100.0]);
        let xs: Vec<f64> = r.opacity_knots().iter().map(|k| k.x).collect();
        assert_eq!(xs, vec![100.0, 1700.0, 2500.0, 4100.0]);
        for (a, b) in [(0.0, 100.0), (2.0, 900.0), (5.0, 2100.0), (10.0, 4100.0)] {
            assert!((tf.opacity(a) - r.opacity(b)).abs() < 1e-6, "{a} vs {b}");
        }
        // A logarithmic axis rescales in log10: the middle decade stays the middle decade.
        let log = TransferFunction::new(
            [1.0, 100.0],
            vec![ColorKnot {
                x: 10.0,
                rgb: [1.0, 1.0, 1.0],
            }],
            vec![OpacityKnot::new(1.0, 0.0), OpacityKnot::new(10.0, 1.0)],
        )
        .unwrap()
        .with_data_axis(DataAxis::Log)
        .unwrap();
        let r = log.rescaled([1e3, 1e7]).unwrap();
        assert!((r.opacity_knots()[1].x - 1e5).abs() < 1e-6);
        assert!(log.rescaled([0.0, 1.0]).is_err());
        assert!(tf.rescaled([2.0, 2.0]).is_err());
    }

    #[test]
    fn straight_segments_interpolate_linearly_between_knots() {
        let tf = ramp();
        assert!((tf.opacity(2.0) - 0.4).abs() < 1e-7);
        assert!((tf.opacity(5.0) - 0.5).abs() < 1e-7);
        assert_eq!(tf.opacity(-3.0), 0.0);
        assert!((tf.opacity(30.0) - 0.4).abs() < 1e-7);
        let c = tf.color(2.5);
        assert!((c[0] - 0.25).abs() < 1e-7);
    }

    #[test]
    fn max_opacity_of_an_interval_between_knots_is_the_larger_end() {
        let tf = ramp();
        // Inside [6, 10] the function rises from 0.2 to 0.4.
        assert_eq!(tf.max_opacity(7.0..=8.0), tf.opacity(8.0));
        // Across the peak knot at 4 the maximum is the knot.
        assert_eq!(tf.max_opacity(3.0..=5.0), 0.8);
        assert_eq!(tf.max_opacity(f64::NAN..=1.0), 0.8);
        assert_eq!(tf.max_opacity(5.0..=3.0), 0.8);
    }

    #[test]
    fn vtk_midpoint_moves_the_half_way_point() {
        // With midpoint 0.25 the curve reaches (y1 + y2) / 2 a quarter of the way along.
        let tf = TransferFunction::new(
            [0.0, 1.0],
            vec![ColorKnot {
                x: 0.0,
                rgb: [1.0; 3],
            }],
            vec![
                OpacityKnot {
                    x: 0.0,
                    alpha: 0.0,
                    midpoint: 0.25,
                    sharpness: 0.0,
                },
                OpacityKnot::new(1.0, 1.0),
            ],
        )
        .unwrap();
        assert!((tf.opacity(0.25) - 0.5).abs() < 1e-7);
        assert!((tf.opacity(0.125) - 0.25).abs() < 1e-7);
    }
}
