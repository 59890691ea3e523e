//! yt's orientation: the default view puts world +x right and +y up, the named views give
//! yt's image axes, framing keeps every corner of the box in the image, zoom magnifies.

use blueshift_camera::{Camera, Projection, View};
use glam::Vec3;

/// Where a world point lands in a `w x h` image of an orthographic camera (pixel units).
fn project_ortho(cam: &Camera, p: Vec3, w: u32, h: u32) -> (f32, f32) {
    let (_, r, u) = cam.basis();
    let Projection::Orthographic { height } = cam.projection else {
        panic!("orthographic camera expected");
    };
    let d = p - cam.target;
    let aspect = w as f32 / h as f32;
    let sx = d.dot(r) / (0.5 * height) / aspect;
    let sy = d.dot(u) / (0.5 * height);
    (
        (sx / 1.0 + 1.0) * 0.5 * w as f32,
        (1.0 - sy) * 0.5 * h as f32,
    )
}

#[test]
fn default_view_puts_plus_x_right_and_plus_y_up() {
    let (lo, hi) = (Vec3::splat(-1.0), Vec3::splat(1.0));
    for ortho in [true, false] {
        let cam = Camera::default_view(lo, hi, 1.0, ortho);
        // The observer sits on the +z side and looks towards -z.
        assert!(cam.eye.z > hi.z, "{cam:?}");
        let (f, r, u) = cam.basis();
        assert!(f.abs_diff_eq(-Vec3::Z, 1e-6), "{f}");
        assert!(r.abs_diff_eq(Vec3::X, 1e-6), "{r}");
        assert!(u.abs_diff_eq(Vec3::Y, 1e-6), "{u}");
        // The ray through the top-right pixel passes the (+x, +y) corner region.
        let ray = cam.ray(63.5, 0.5, 64, 64);
        let (t0, _) = ray.clip_box(lo, hi).expect("the corner ray hits the box");
        let p = ray.at(t0);
        assert!(p.x > 0.8 && p.y > 0.8, "{p}");
    }
}

#[test]
fn named_views_follow_yt_image_axes() {
    // (view, forward, right, up)
    let cases = [
        (View::Z, -Vec3::Z, Vec3::X, Vec3::Y),
        (View::X, -Vec3::X, Vec3::Y, Vec3::Z),
        (View::Y, -Vec3::Y, Vec3::Z, Vec3::X),
        (View::NegZ, Vec3::Z, -Vec3::X, Vec3::Y),
        (View::NegX, Vec3::X, -Vec3::Y, Vec3::Z),
        (View::NegY, Vec3::Y, -Vec3::Z, Vec3::X),
    ];
    let (lo, hi) = (Vec3::new(-1.0, -2.0, -3.0), Vec3::new(2.0, 1.0, 0.5));
    for (view, fw, rt, up) in cases {
        let cam = Camera::view_of(lo, hi, view, 1.0, true);
        let (f, r, u) = cam.basis();
        assert!(f.abs_diff_eq(fw, 1e-6), "{view}: forward {f}");
        assert!(r.abs_diff_eq(rt, 1e-6), "{view}: right {r}");
        assert!(u.abs_diff_eq(up, 1e-6), "{view}: up {u}");
    }
    // iso: from the (1,1,1) diagonal with z up; right is (-1, 1, 0)/sqrt 2.
    let cam = Camera::view_of(lo, hi, View::Iso, 1.0, true);
    let (f, r, u) = cam.basis();
    assert!(f.abs_diff_eq(-Vec3::ONE.normalize(), 1e-6));
    assert!(
        r.abs_diff_eq(Vec3::new(-1.0, 1.0, 0.0).normalize(), 1e-6),
        "{r}"
    );
    assert!(u.z > 0.0);
    for (name, v) in View::NAMES.iter().zip(View::ALL) {
        assert_eq!(name.parse::<View>().unwrap(), v);
        assert_eq!(v.to_string(), *name);
    }
    assert_eq!("+Z".parse::<View>().unwrap(), View::Z);
    assert!("w".parse::<View>().is_err());
}

#[test]
fn framing_keeps_every_corner_inside_and_touches_one_edge() {
    let (lo, hi) = (Vec3::new(-15.0, -15.0, -7.5), Vec3::new(15.0, 15.0, 7.5));
    for deg in [0.0f32, 30.0, 60.0, 90.0] {
        let (s, c) = deg.to_radians().sin_cos();
        let cam = Camera::framing(
            lo,
            hi,
            Vec3::new(0.0, s, c),
            Vec3::new(0.0, c, -s),
            2.0,
            true,
            30.0,
        )
        .unwrap();
        let (w, h) = (200, 100);
        let mut extreme = 0.0f32;
        for i in 0..8 {
            let p = Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            let (x, y) = project_ortho(&cam, p, w, h);
            assert!(
                (-1e-3..=w as f32 + 1e-3).contains(&x) && (-1e-3..=h as f32 + 1e-3).contains(&y),
                "{deg} deg: corner {p} at ({x}, {y})"
            );
            extreme = extreme.max((x / w as f32 - 0.5).abs().max((y / h as f32 - 0.5).abs()));
        }
        assert!(
            (extreme - 0.5).abs() < 1e-4,
            "{deg} deg: not tight ({extreme})"
        );
    }
    // Perspective: the eye stands outside the box on the +normal side.
    let cam = Camera::framing(lo, hi, Vec3::Z, Vec3::Y, 1.0, false, 20.0).unwrap();
    assert!(cam.eye.z > hi.z);
    assert!(Camera::framing(lo, hi, Vec3::ZERO, Vec3::Y, 1.0, true, 30.0).is_err());
    assert!(Camera::framing(lo, hi, Vec3::Y, Vec3::Y, 1.0, true, 30.0).is_err());
}

#[test]
fn zoom_magnifies_about_the_centre() {
    let (lo, hi) = (Vec3::splat(-1.0), Vec3::splat(1.0));
    let cam = Camera::default_view(lo, hi, 1.0, true);
    let z = cam.zoomed(4.0).unwrap();
    assert_eq!(z.projection, Projection::Orthographic { height: 0.5 });
    let p = Camera::default_view(lo, hi, 1.0, false);
    let Projection::Perspective { fov_y_deg: f0 } = p.projection else {
        panic!()
    };
    let Projection::Perspective { fov_y_deg: f1 } = p.zoomed(2.0).unwrap().projection else {
        panic!()
    };
    let ratio = (f0.to_radians() / 2.0).tan() / (f1.to_radians() / 2.0).tan();
    assert!((ratio - 2.0).abs() < 1e-5, "{ratio}");
    assert!(cam.zoomed(0.0).is_err() && cam.zoomed(f32::NAN).is_err());
    // A zoom that overflows the view names the zoom (it was reported as a bad height).
    let e = cam.zoomed(1e-39).unwrap_err().to_string();
    assert!(
        e.starts_with("invalid parameter: zoom") && e.contains("out of range"),
        "{e}"
    );
}

/// Views set by eye and target choose the same up, and give the same rays up to scale, in
/// any unit of length: directions are normalised before their squares are taken (at 1e21
/// or 1e-30 per unit the squares over- or underflow f32, and an up that is not parallel
/// was replaced, or a valid view refused as "up is parallel").
#[test]
fn overrides_choose_the_same_up_in_any_unit_of_length() {
    use blueshift_camera::Camera;
    use glam::Vec3;
    let view = |s: f32| {
        Camera::default_view(Vec3::ZERO, Vec3::splat(8.0 * s), 1.0, false).with_overrides(
            Some(Vec3::new(4.0, 40.0, 4.0) * s),
            Some(Vec3::splat(4.0 * s)),
            None,
        )
    };
    let reference = view(1.0);
    reference.validate().unwrap();
    for s in [1e-30f32, 1e-12, 1e21, 1e30] {
        let c = view(s);
        c.validate().unwrap_or_else(|e| panic!("{s}: {e}"));
        assert!(
            c.up.abs_diff_eq(reference.up, 1e-6),
            "{s}: up {} vs {}",
            c.up,
            reference.up
        );
        let (a, b) = (c.basis(), reference.basis());
        assert!(
            a.0.abs_diff_eq(b.0, 1e-6) && a.1.abs_diff_eq(b.1, 1e-6),
            "{s}"
        );
    }
    // Looking along an axis at any scale takes yt's up for that axis.
    for s in [1e-30f32, 1.0, 1e30] {
        let c = Camera::default_view(Vec3::ZERO, Vec3::splat(s), 1.0, false).with_overrides(
            Some(Vec3::new(0.5, 0.5, 10.0) * s),
            Some(Vec3::splat(0.5 * s)),
            None,
        );
        assert_eq!(c.up, blueshift_camera::up_for(Vec3::Z), "{s}");
    }
}
