//! The page and its ES modules, embedded in the binary (no build step, no network).

/// Every served file: name, bytes, MIME type.
const FILES: &[(&str, &[u8], &str)] = &[
    (
        "index.html",
        include_bytes!("../assets/index.html"),
        "text/html; charset=utf-8",
    ),
    (
        "style.css",
        include_bytes!("../assets/style.css"),
        "text/css; charset=utf-8",
    ),
    (
        "app.js",
        include_bytes!("../assets/app.js"),
        "text/javascript; charset=utf-8",
    ),
    (
        "net.js",
        include_bytes!("../assets/net.js"),
        "text/javascript; charset=utf-8",
    ),
    (
        "view3d.js",
        include_bytes!("../assets/view3d.js"),
        "text/javascript; charset=utf-8",
    ),
    (
        "tf.js",
        include_bytes!("../assets/tf.js"),
        "text/javascript; charset=utf-8",
    ),
    (
        "fisheye.js",
        include_bytes!("../assets/fisheye.js"),
        "text/javascript; charset=utf-8",
    ),
    (
        "plot.js",
        include_bytes!("../assets/plot.js"),
        "text/javascript; charset=utf-8",
    ),
    (
        "panels.js",
        include_bytes!("../assets/panels.js"),
        "text/javascript; charset=utf-8",
    ),
];

/// The bytes and MIME type of a served file.
pub(crate) fn get(name: &str) -> Option<(&'static [u8], &'static str)> {
    FILES
        .iter()
        .find(|(n, _, _)| *n == name)
        .map(|(_, b, m)| (*b, *m))
}
