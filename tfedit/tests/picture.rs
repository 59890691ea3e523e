//! The editor-view picture (HDR VolVis Fig. 6c / 7).
#![cfg(feature = "picture")]

use blueshift_tfedit::picture::{EditorView, render_editor_view};
use blueshift_tfedit::{ColorKnot, Fisheye, FocusRegion, OpacityKnot, TransferFunction, ValueAxis, builtin_over};

#[test]
fn focus_bar_is_m_c_times_wider_than_the_focus_region() {
    let tf = builtin_over("viridis", [0.0, 1000.0]).unwrap();
    let focus = FocusRegion { center: 0.3, width: 0.05, magnification: 6.0, transition: 0.02 };
    let view = EditorView { fisheye: Fisheye::new(vec![focus]).unwrap(), ..EditorView::default() };
    let img = render_editor_view(&tf, &view).unwrap();
    let lay = view.layout().unwrap();
    assert_eq!(img.dimensions(), (1024, 512));
    let y = (lay.focus_y.0 + lay.focus_y.1) / 2;
    let green = (lay.x0..lay.x1).filter(|&x| img.get_pixel(x, y).0 == [40, 200, 60]).count();
    // The focus covers 0.05 of the data axis and M_c = 6 times that of the window.
    let expected = 0.05 * 6.0 * f64::from(lay.x1 - lay.x0);
    assert!((green as f64 - expected).abs() <= 2.0, "green columns {green}, expected {expected}");
}

#[test]
fn colour_bar_shows_the_colour_at_each_fisheye_column() {
    let tf = builtin_over("inferno", [10.0, 20.0]).unwrap();
    let fisheye = Fisheye::new(vec![FocusRegion { center: 0.7, width: 0.1, magnification: 3.0, transition: 0.05 }]).unwrap();
    let view = EditorView { fisheye: fisheye.clone(), ..EditorView::default() };
    let img = render_editor_view(&tf, &view).unwrap();
    let lay = view.layout().unwrap();
    let y = (lay.colorbar_y.0 + lay.colorbar_y.1) / 2;
    for v in [10.5, 13.0, 16.8, 17.0, 17.2, 19.5] {
        // Column of value v through the fisheye; the pixel shows tf.color at its centre.
        let col = lay.window_to_column(fisheye.forward(tf.normalized(v)));
        let centre_value = tf.value_at_normalized(fisheye.inverse(lay.column_to_window(col)));
        let c = tf.color(centre_value).map(|c| (c * 255.0).round() as u8);
        assert_eq!(img.get_pixel(col, y).0, c, "value {v} at column {col}");
        // And that is close to the colour at v itself (columns are narrow).
        let cv = tf.color(v).map(|c| c * 255.0);
        for k in 0..3 {
            assert!((f32::from(c[k]) - cv[k]).abs() <= 3.0, "value {v}: {c:?} vs {cv:?}");
        }
    }
}

#[test]
fn log_opacity_axis_puts_one_percent_half_way_up_with_a_1e_minus_4_floor() {
    // Constant opacity 0.01 on a log axis with floor 1e-4: log10(0.01) is half way between
    // -4 and 0, so the filled area reaches the middle of the plot.
    let tf = TransferFunction::new(
        [0.0, 1.0],
        vec![ColorKnot { x: 0.0, rgb: [1.0, 0.0, 0.0] }],
        vec![OpacityKnot::new(0.0, 0.01)],
    )
    .unwrap();
    let view = EditorView { opacity_axis: ValueAxis::log(1e-4).unwrap(), ..EditorView::default() };
    let img = render_editor_view(&tf, &view).unwrap();
    let lay = view.layout().unwrap();
    let mid = (f64::from(lay.plot_y.0) + f64::from(lay.plot_y.1)) / 2.0;
    let x = lay.x0 + 300;
    assert_eq!(img.get_pixel(x, (mid + 4.0) as u32).0, [255, 0, 0], "below the curve is filled");
    assert_ne!(img.get_pixel(x, (mid - 4.0) as u32).0, [255, 0, 0], "above the curve is empty");
    // On a linear axis 0.01 hugs the bottom.
    let lin = render_editor_view(&tf, &EditorView::default()).unwrap();
    assert_ne!(lin.get_pixel(x, (mid + 4.0) as u32).0, [255, 0, 0]);
}

#[test]
fn absurd_sizes_are_refused() {
    let tf = builtin_over("grey", [0.0, 1.0]).unwrap();
    for (w, h) in [(0, 100), (100_000, 500), (1024, 10)] {
        let view = EditorView { width: w, height: h, ..EditorView::default() };
        assert!(render_editor_view(&tf, &view).is_err(), "{w} x {h} accepted");
    }
}
