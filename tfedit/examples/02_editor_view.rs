//! Draws the editor view of HDR VolVis Fig. 7: a transfer function for heavy-tailed data on a
//! log data axis, two focus regions magnified by a fisheye, and a logarithmic opacity axis.
//!
//! Run with `cargo run -p blueshift-tfedit --example 02_editor_view -- editor.png`.

use blueshift_tfedit::picture::{EditorView, render_editor_view};
use blueshift_tfedit::{
    ColorKnot, ColorSpace, DataAxis, Fisheye, FocusRegion, OpacityKnot, TransferFunction,
    ValueAxis,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args().nth(1).unwrap_or_else(|| "editor.png".into());
    // Vorticity-like data spanning five decades; colours interpolated in HSV (section 5).
    let tf = TransferFunction::new(
        [1e-2, 1e3],
        vec![
            ColorKnot { x: 1e-2, rgb: [0.1, 0.1, 0.9] },
            ColorKnot { x: 1.0, rgb: [0.1, 0.9, 0.3] },
            ColorKnot { x: 1e3, rgb: [0.95, 0.2, 0.1] },
        ],
        vec![
            OpacityKnot::new(1e-2, 1e-4),
            OpacityKnot::new(0.5, 2e-3),
            OpacityKnot::new(0.8, 0.05),
            OpacityKnot::new(1.1, 1e-3),
            OpacityKnot::new(50.0, 0.01),
            OpacityKnot::new(80.0, 0.6),
            OpacityKnot::new(1e3, 0.2),
        ],
    )?
    .with_color_space(ColorSpace::Hsv)
    .with_data_axis(DataAxis::Log)?
    .with_name("vorticity");
    // Focus on [0.5, 1.1] and [50, 80]: centre and width on the normalised log axis.
    let focus = |a: f64, b: f64, m: f64| {
        let (ta, tb) = (tf.normalized(a), tf.normalized(b));
        FocusRegion { center: 0.5 * (ta + tb), width: tb - ta, magnification: m, transition: 0.03 }
    };
    let view = EditorView {
        fisheye: Fisheye::new(vec![focus(0.5, 1.1, 4.0), focus(50.0, 80.0, 3.0)])?,
        opacity_axis: ValueAxis::log(1e-4)?,
        ..EditorView::default()
    };
    render_editor_view(&tf, &view)?.save(&out)?;
    println!("wrote {out} (M_min = {:.3})", view.fisheye.m_min());
    Ok(())
}
