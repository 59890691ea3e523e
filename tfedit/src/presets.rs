//! Built-in colour maps, from published control points, each with a straight 0-to-1 opacity
//! ramp over the domain [0, 1] ([`builtin_over`] stretches one over a data range).
//!
//! Sources:
//! - `viridis`, `inferno`: matplotlib's colour maps by Nathaniel J. Smith and Stefan van der
//!   Walt (CC0, <https://github.com/BIDS/colormap/blob/master/colormaps.py>), as carried by
//!   ParaView's `Remoting/Views/ColorMaps.json` ("Viridis", "Inferno"), sampled at 33 of
//!   the 256 entries (every 8th and the last) and interpolated in RGB.
//! - `cool-warm`: Kenneth Moreland, "Diverging Color Maps for Scientific Visualization"
//!   (ISVC 2009), the three control points of ParaView's "Cool to Warm", interpolated in
//!   the diverging Msh space.
//! - `black-body`: ParaView's "Black-Body Radiation" (Kindlmann's black-body map), RGB.
//! - `grey`: black to white in RGB (ParaView's "Grayscale").

use crate::color::ColorSpace;
use crate::tf::{ColorKnot, OpacityKnot, TransferFunction};
use crate::{Error, Result};

/// Names accepted by [`builtin`].
pub const BUILTIN_NAMES: [&str; 5] = ["viridis", "inferno", "cool-warm", "black-body", "grey"];

/// Viridis: matplotlib entries 0, 8, ..., 248, 255 (of 256), x = index / 255.
const VIRIDIS: [[f64; 4]; 33] = [
    [0.0, 0.267004, 0.004874, 0.329415],
    [0.03137254901960784, 0.277018, 0.050344, 0.375715],
    [0.06274509803921569, 0.282327, 0.094955, 0.417331],
    [0.09411764705882353, 0.282884, 0.13592, 0.453427],
    [0.12549019607843137, 0.278826, 0.17549, 0.483397],
    [0.1568627450980392, 0.270595, 0.214069, 0.507052],
    [0.18823529411764706, 0.258965, 0.251537, 0.524736],
    [0.2196078431372549, 0.244972, 0.287675, 0.53726],
    [0.25098039215686274, 0.229739, 0.322361, 0.545706],
    [0.2823529411764706, 0.214298, 0.355619, 0.551184],
    [0.3137254901960784, 0.19943, 0.387607, 0.554642],
    [0.34509803921568627, 0.185556, 0.41857, 0.556753],
    [0.3764705882352941, 0.172719, 0.448791, 0.557885],
    [0.40784313725490196, 0.160665, 0.47854, 0.558115],
    [0.4392156862745098, 0.149039, 0.508051, 0.55725],
    [0.47058823529411764, 0.13777, 0.537492, 0.554906],
    [0.5019607843137255, 0.127568, 0.566949, 0.550556],
    [0.5333333333333333, 0.120565, 0.596422, 0.543611],
    [0.5647058823529412, 0.120638, 0.625828, 0.533488],
    [0.596078431372549, 0.132268, 0.655014, 0.519661],
    [0.6274509803921569, 0.157851, 0.683765, 0.501686],
    [0.6588235294117647, 0.196571, 0.711827, 0.479221],
    [0.6901960784313725, 0.24607, 0.73891, 0.452024],
    [0.7215686274509804, 0.304148, 0.764704, 0.419943],
    [0.7529411764705882, 0.369214, 0.788888, 0.382914],
    [0.7843137254901961, 0.440137, 0.811138, 0.340967],
    [0.8156862745098039, 0.515992, 0.831158, 0.294279],
    [0.8470588235294118, 0.595839, 0.848717, 0.243329],
    [0.8784313725490196, 0.678489, 0.863742, 0.189503],
    [0.9098039215686274, 0.762373, 0.876424, 0.137064],
    [0.9411764705882353, 0.845561, 0.887322, 0.099702],
    [0.9725490196078431, 0.926106, 0.89733, 0.104071],
    [1.0, 0.993248, 0.906157, 0.143936],
];
/// Inferno: matplotlib entries 0, 8, ..., 248, 255 (of 256), x = index / 255.
const INFERNO: [[f64; 4]; 33] = [
    [0.0, 0.001462, 0.000466, 0.013866],
    [0.03137254901960784, 0.013995, 0.011225, 0.071862],
    [0.06274509803921569, 0.042253, 0.028139, 0.141141],
    [0.09411764705882353, 0.081962, 0.043328, 0.215289],
    [0.12549019607843137, 0.129285, 0.047293, 0.290788],
    [0.1568627450980392, 0.183429, 0.040329, 0.354971],
    [0.18823529411764706, 0.238273, 0.036621, 0.396353],
    [0.2196078431372549, 0.290763, 0.045644, 0.418637],
    [0.25098039215686274, 0.3415, 0.062325, 0.429425],
    [0.2823529411764706, 0.391453, 0.080927, 0.433109],
    [0.3137254901960784, 0.441207, 0.099338, 0.431594],
    [0.34509803921568627, 0.491022, 0.117179, 0.425552],
    [0.3764705882352941, 0.54092, 0.134729, 0.415123],
    [0.40784313725490196, 0.590734, 0.152563, 0.40029],
    [0.4392156862745098, 0.640135, 0.171438, 0.381065],
    [0.47058823529411764, 0.688653, 0.192239, 0.357603],
    [0.5019607843137255, 0.735683, 0.215906, 0.330245],
    [0.5333333333333333, 0.780517, 0.243327, 0.299523],
    [0.5647058823529412, 0.822386, 0.275197, 0.266085],
    [0.596078431372549, 0.860533, 0.311892, 0.230606],
    [0.6274509803921569, 0.894305, 0.353399, 0.193584],
    [0.6588235294117647, 0.923215, 0.399359, 0.155193],
    [0.6901960784313725, 0.946965, 0.449191, 0.115272],
    [0.7215686274509804, 0.965397, 0.502249, 0.073859],
    [0.7529411764705882, 0.978422, 0.557937, 0.034931],
    [0.7843137254901961, 0.985952, 0.61575, 0.025592],
    [0.8156862745098039, 0.987874, 0.675267, 0.065257],
    [0.8470588235294118, 0.984075, 0.736087, 0.129527],
    [0.8784313725490196, 0.974638, 0.797692, 0.206332],
    [0.9098039215686274, 0.960626, 0.859069, 0.29801],
    [0.9411764705882353, 0.947594, 0.917399, 0.410665],
    [0.9725490196078431, 0.954529, 0.965896, 0.540361],
    [1.0, 0.988362, 0.998364, 0.644924],
];

/// ParaView "Cool to Warm" (Moreland 2009): x, r, g, b.
const COOL_WARM: [[f64; 4]; 3] = [
    [0.0, 0.23137254902, 0.298039215686, 0.752941176471],
    [0.5, 0.865, 0.865, 0.865],
    [1.0, 0.705882352941, 0.0156862745098, 0.149019607843],
];

/// ParaView "Black-Body Radiation": x, r, g, b.
const BLACK_BODY: [[f64; 4]; 4] = [
    [0.0, 0.0, 0.0, 0.0],
    [0.4, 0.901960784314, 0.0, 0.0],
    [0.8, 0.901960784314, 0.901960784314, 0.0],
    [1.0, 1.0, 1.0, 1.0],
];

const GREY: [[f64; 4]; 2] = [[0.0, 0.0, 0.0, 0.0], [1.0, 1.0, 1.0, 1.0]];

/// A built-in map over [0, 1] with a 0-to-1 opacity ramp. `name` is one of
/// [`BUILTIN_NAMES`] (`gray` and `coolwarm` are accepted too).
pub fn builtin(name: &str) -> Result<TransferFunction> {
    let (knots, space, canonical): (&[[f64; 4]], ColorSpace, &str) = match name {
        "viridis" => (&VIRIDIS, ColorSpace::Rgb, "viridis"),
        "inferno" => (&INFERNO, ColorSpace::Rgb, "inferno"),
        "cool-warm" | "coolwarm" => (&COOL_WARM, ColorSpace::Diverging, "cool-warm"),
        "black-body" | "blackbody" => (&BLACK_BODY, ColorSpace::Rgb, "black-body"),
        "grey" | "gray" => (&GREY, ColorSpace::Rgb, "grey"),
        other => {
            return Err(Error::parameter(format!(
                "no built-in colour map {other:?}; the built-ins are {BUILTIN_NAMES:?}"
            )));
        }
    };
    let color = knots
        .iter()
        .map(|k| ColorKnot {
            x: k[0],
            rgb: [k[1] as f32, k[2] as f32, k[3] as f32],
        })
        .collect();
    let opacity = vec![OpacityKnot::new(0.0, 0.0), OpacityKnot::new(1.0, 1.0)];
    Ok(TransferFunction::new([0.0, 1.0], color, opacity)?
        .with_color_space(space)
        .with_name(canonical))
}

/// A built-in map stretched over the data domain `[min, max]` (knots rescaled).
pub fn builtin_over(name: &str, domain: [f64; 2]) -> Result<TransferFunction> {
    let base = builtin(name)?;
    let [lo, hi] = domain;
    if !(lo.is_finite() && hi.is_finite()) || lo >= hi {
        return Err(Error::parameter(format!(
            "domain [{lo}, {hi}] must be finite with min < max"
        )));
    }
    let map = |x: f64| lo + (hi - lo) * x;
    let color = base
        .color_knots()
        .iter()
        .map(|k| ColorKnot { x: map(k.x), ..*k })
        .collect();
    let opacity = base
        .opacity_knots()
        .iter()
        .map(|k| OpacityKnot { x: map(k.x), ..*k })
        .collect();
    Ok(TransferFunction::new(domain, color, opacity)?
        .with_color_space(base.color_space())
        .with_name(base.name()))
}
