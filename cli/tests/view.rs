//! `blueshift view` end to end over its real socket: the token and the Host/Origin checks,
//! the WebSocket protocol (frames, malformed messages, several tabs), and "save", whose
//! printed command must write the same EXR bit for bit. The browser tests
//! (`view/tests/browser/`) drive the page itself.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use tungstenite::{Message, WebSocket, stream::MaybeTlsStream};

const BIN: &str = env!("CARGO_BIN_EXE_blueshift");

/// A running `blueshift view`, killed when dropped.
struct Viewer {
    child: Child,
    url: String,
    dir: tempfile::TempDir,
}

impl Drop for Viewer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Viewer {
    fn start(args: &[&str]) -> Viewer {
        let dir = tempfile::tempdir().unwrap();
        let mut child = Command::new(BIN)
            .arg("view")
            .args(args)
            .args(["--port", "0", "--save-dir"])
            .arg(dir.path().join("saved"))
            .current_dir(dir.path())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let url = line
            .trim()
            .strip_prefix("blueshift view: ")
            .unwrap_or_else(|| panic!("first line: {line:?}"))
            .to_owned();
        Viewer { child, url, dir }
    }

    /// `host:port`.
    fn authority(&self) -> String {
        self.url
            .trim_start_matches("http://")
            .split('/')
            .next()
            .unwrap()
            .to_owned()
    }

    fn token(&self) -> String {
        self.url
            .trim_end_matches('/')
            .rsplit('/')
            .next()
            .unwrap()
            .to_owned()
    }

    fn connect(&self) -> Tab {
        let ws = format!("ws://{}/{}/ws", self.authority(), self.token());
        let (mut socket, _) = tungstenite::connect(ws).unwrap();
        if let MaybeTlsStream::Plain(s) = socket.get_mut() {
            s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
        }
        Tab {
            socket,
            frames: Default::default(),
            texts: Default::default(),
        }
    }
}

/// The status code of a GET with the given Host and Origin headers.
fn get(authority: &str, path: &str, host: &str, origin: Option<&str>) -> u16 {
    let mut s = TcpStream::connect(authority).unwrap();
    let origin = origin
        .map(|o| format!("Origin: {o}\r\n"))
        .unwrap_or_default();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: {host}\r\n{origin}Connection: close\r\n\r\n"
    )
    .unwrap();
    let mut buf = String::new();
    let _ = s.read_to_string(&mut buf);
    buf.split_whitespace().nth(1).unwrap().parse().unwrap()
}

struct Tab {
    socket: WebSocket<MaybeTlsStream<TcpStream>>,
    /// Frames that arrived while a text message was awaited (the page gets frames and text
    /// on separate queues, so their order is not fixed).
    frames: std::collections::VecDeque<Frame>,
    /// Text messages that arrived while a frame was awaited.
    texts: std::collections::VecDeque<Value>,
}

/// A frame's JSON header and PNG.
struct Frame {
    header: Value,
    png: Vec<u8>,
}

enum Got {
    Text(Value),
    Frame(Frame),
}

impl Tab {
    fn send(&mut self, v: &Value) {
        self.socket.send(Message::text(v.to_string())).unwrap();
    }

    fn send_raw(&mut self, s: &str) {
        self.socket.send(Message::text(s.to_owned())).unwrap();
    }

    fn next(&mut self) -> Got {
        loop {
            match self.socket.read().unwrap() {
                Message::Text(t) => return Got::Text(serde_json::from_str(t.as_str()).unwrap()),
                Message::Binary(b) => {
                    let n = u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize;
                    let header = serde_json::from_slice(&b[4..4 + n]).unwrap();
                    return Got::Frame(Frame {
                        header,
                        png: b[4 + n..].to_vec(),
                    });
                }
                _ => {}
            }
        }
    }

    /// The next text message of `kind` (others are skipped); panics on an `error` unless
    /// that is what is awaited.
    fn expect(&mut self, kind: &str) -> Value {
        while let Some(v) = self.texts.pop_front() {
            if v["type"] == kind {
                return v;
            }
            assert_ne!(v["type"], "error", "waiting for {kind}: {v}");
        }
        let t0 = Instant::now();
        loop {
            assert!(t0.elapsed() < Duration::from_secs(120), "no {kind} message");
            match self.next() {
                Got::Text(v) => {
                    if v["type"] == kind {
                        return v;
                    }
                    assert_ne!(v["type"], "error", "waiting for {kind}: {v}");
                }
                Got::Frame(f) => self.frames.push_back(f),
            }
        }
    }

    /// Waits for the status of a finished full-resolution render.
    fn until_done(&mut self) -> Value {
        loop {
            let s = self.expect("status");
            if s["done"] == true {
                return s;
            }
        }
    }

    fn frame(&mut self) -> Frame {
        if let Some(f) = self.frames.pop_front() {
            return f;
        }
        let t0 = Instant::now();
        loop {
            assert!(t0.elapsed() < Duration::from_secs(120), "no frame");
            match self.next() {
                Got::Frame(f) => return f,
                Got::Text(v) => {
                    assert_ne!(v["type"], "error", "waiting for a frame: {v}");
                    self.texts.push_back(v);
                }
            }
        }
    }
}

/// Runs a printed command line (plain words, no quoting needed for these paths) with the
/// test's binary.
fn run_command(cmd: &str, extra: &[&str]) -> std::process::Output {
    let words: Vec<&str> = cmd.split_whitespace().collect();
    assert_eq!(words[0], "blueshift", "{cmd}");
    let out = Command::new(BIN)
        .args(&words[1..])
        .args(extra)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{cmd}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn saved_file(saved: &Value, ext: &str) -> PathBuf {
    PathBuf::from(
        saved["files"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f.as_str().unwrap())
            .find(|f| f.ends_with(ext))
            .unwrap(),
    )
}

/// Renames the viewer's file aside, runs the command (which writes the same path) and
/// compares the bytes.
fn command_reproduces(saved: &Value, ext: &str) {
    let file = saved_file(saved, ext);
    let aside = file.with_extension(format!("viewer{ext}"));
    std::fs::rename(&file, &aside).unwrap();
    run_command(saved["command"].as_str().unwrap(), &[]);
    let (a, b) = (
        std::fs::read(&aside).unwrap(),
        std::fs::read(&file).unwrap(),
    );
    assert!(
        a == b,
        "{}: the command's {ext} differs from the viewer's",
        saved["command"]
    );
}

#[test]
fn the_viewer_refuses_without_its_token_or_from_a_foreign_host() {
    let v = Viewer::start(&[
        "--synth",
        "three-cubes",
        "--res",
        "16",
        "--width",
        "16",
        "--height",
        "16",
    ]);
    let a = v.authority();
    let port = a.rsplit(':').next().unwrap().to_owned();
    let t = v.token();
    assert!(v.url.starts_with("http://127.0.0.1:"), "{}", v.url);
    assert_eq!(get(&a, &format!("/{t}/"), &a, None), 200);
    assert_eq!(get(&a, &format!("/{t}/app.js"), &a, None), 200);
    assert_eq!(
        get(&a, &format!("/{t}/"), &format!("localhost:{port}"), None),
        200
    );
    let wrong = "0".repeat(t.len());
    for path in [
        "/",
        "/app.js",
        &format!("/{wrong}/"),
        &format!("/{wrong}/app.js"),
        &format!("/{wrong}/ws"),
    ] {
        assert_eq!(get(&a, path, &a, None), 404, "{path}");
    }
    // DNS rebinding: the right token under a foreign Host or Origin.
    assert_eq!(
        get(&a, &format!("/{t}/"), &format!("evil.example:{port}"), None),
        403
    );
    assert_eq!(get(&a, &format!("/{t}/"), "evil.example", None), 403);
    assert_eq!(
        get(
            &a,
            &format!("/{t}/"),
            &a,
            Some(&format!("http://evil.example:{port}"))
        ),
        403
    );
    assert_eq!(
        get(&a, &format!("/{t}/"), &a, Some(&format!("http://{a}"))),
        200
    );
    // The WebSocket without the token does not open.
    assert!(tungstenite::connect(format!("ws://{a}/{wrong}/ws")).is_err());
    assert!(tungstenite::connect(format!("ws://{a}/ws")).is_err());
}

#[test]
fn a_malformed_message_gets_an_error_and_the_next_frame_still_arrives() {
    let v = Viewer::start(&[
        "--synth",
        "three-cubes",
        "--res",
        "16",
        "--width",
        "24",
        "--height",
        "24",
        "--spp",
        "2",
    ]);
    let mut tab = v.connect();
    let info = tab.expect("info");
    assert_eq!(info["mode"], "tracking");
    assert_eq!(info["channels"].as_array().unwrap().len(), 3);
    let f = tab.frame();
    assert_eq!(&f.png[..8], b"\x89PNG\r\n\x1a\n");
    tab.until_done();
    for bad in [
        "garbage",
        "{\"type\":\"pick\",\"x\":\"a\",\"y\":1}",
        "{\"type\":\"settings\",\"spp\":0}",
        "{\"type\":\"tf\",\"channel\":9,\"tf\":{}}",
        "{\"type\":\"camera\",\"eye\":[0,0,0],\"target\":[0,0,0],\"up\":[0,1,0]}",
    ] {
        tab.send_raw(bad);
        let e = tab.expect("error");
        let msg = e["message"].as_str().unwrap();
        assert!(!msg.is_empty() && !msg.contains('\n'), "{bad}: {e}");
    }
    tab.send(&json!({"type": "view", "name": "iso"}));
    let cam = tab.expect("camera");
    assert_eq!(cam["view"], "iso");
    let f = tab.frame();
    assert!(f.header["seq"].as_u64().unwrap() > 0);
    tab.until_done();
}

#[test]
fn tabs_have_their_own_sessions() {
    let v = Viewer::start(&[
        "--synth",
        "three-cubes",
        "--res",
        "16",
        "--width",
        "20",
        "--height",
        "20",
        "--spp",
        "1",
    ]);
    let mut a = v.connect();
    let mut b = v.connect();
    a.expect("info");
    b.expect("info");
    a.until_done();
    b.until_done();
    a.send(&json!({"type": "settings", "width": 12, "height": 10}));
    assert_eq!(a.expect("settings")["width"], 12);
    let s = a.until_done();
    assert_eq!(s["spp"], 1);
    b.send(&json!({"type": "hello"}));
    let info = b.expect("info");
    assert_eq!(info["width"], 20, "tab b must keep its own size");
    b.send(&json!({"type": "settings", "seed": 3}));
    assert_eq!(b.expect("settings")["width"], 20);
    // Each tab's frames have its own size.
    b.until_done();
    for (tab, width) in [(&mut a, 12), (&mut b, 20)] {
        tab.frames.clear();
        tab.texts.clear();
        tab.send(&json!({"type": "settings", "seed": 4}));
        let mut f = tab.frame();
        while f.header["preview"] == true {
            f = tab.frame();
        }
        assert_eq!(f.header["width"], width);
        tab.until_done();
    }
}

#[test]
fn a_tracking_save_writes_the_exr_its_command_writes() {
    let v = Viewer::start(&[
        "--synth",
        "three-cubes",
        "--res",
        "20",
        "--width",
        "40",
        "--height",
        "32",
        "--spp",
        "3",
    ]);
    let mut tab = v.connect();
    let info = tab.expect("info");
    tab.until_done();
    // Edit the first channel's opacity, orbit the camera, change the method: the saved
    // scene must carry all of it.
    let mut tf = info["channels"][0]["tf"].clone();
    tf["opacity"][0]["alpha"] = json!(0.3);
    tab.send(&json!({"type": "tf", "channel": 0, "tf": tf}));
    tab.expect("tf");
    let cam = &info["camera"];
    let eye: Vec<f64> = cam["eye"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    tab.send(
        &json!({"type": "camera", "eye": [eye[0] + 0.7, eye[1] - 0.3, eye[2]],
                     "target": cam["target"], "up": cam["up"], "fov": 25.0}),
    );
    tab.expect("camera");
    tab.send(&json!({"type": "settings", "method": "mdwt-ndda", "blend": "max", "seed": 7}));
    tab.expect("settings");
    let done = tab.until_done();
    assert_eq!(done["spp"], 3);
    tab.send(&json!({"type": "save", "name": "orbit"}));
    let saved = tab.expect("saved");
    let cmd = saved["command"].as_str().unwrap();
    assert!(cmd.starts_with("blueshift render "), "{cmd}");
    command_reproduces(&saved, ".exr");
    // The saved scene names the edits.
    let scene: Value =
        serde_json::from_str(&std::fs::read_to_string(saved["scene"].as_str().unwrap()).unwrap())
            .unwrap();
    assert_eq!(scene["method"], "mdwt-ndda");
    assert_eq!(scene["spp"], 3);
}

/// The flux-weighted centroid of a CSV spectrum (`wavelength_nm,value`, exact polyline
/// points) over [a, b], by the trapezoid moments of each segment.
fn csv_centroid(csv: &str, a: f64, b: f64) -> f64 {
    let pts: Vec<(f64, f64)> = csv
        .lines()
        .skip(1)
        .map(|l| {
            let (x, y) = l.split_once(',').unwrap();
            (x.parse().unwrap(), y.parse().unwrap())
        })
        .collect();
    let (mut m0, mut m1) = (0.0, 0.0);
    for w in pts.windows(2) {
        let ((x0, y0), (x1, y1)) = (w[0], w[1]);
        let (l0, l1) = (x0.max(a), x1.min(b));
        if l1 <= l0 || x1 <= x0 {
            continue;
        }
        let at = |x: f64| y0 + (y1 - y0) * (x - x0) / (x1 - x0);
        let (f0, f1) = (at(l0), at(l1));
        let d = l1 - l0;
        m0 += 0.5 * (f0 + f1) * d;
        m1 += d * (f0 * (2.0 * l0 + l1) + f1 * (l0 + 2.0 * l1)) / 6.0;
    }
    m1 / m0
}

#[test]
fn a_doppler_pick_has_the_centroids_of_the_cli_pick_and_save_reproduces() {
    let v = Viewer::start(&[
        "--synth",
        "galaxy",
        "--doppler",
        "--res",
        "24",
        "--width",
        "48",
        "--height",
        "48",
    ]);
    let mut tab = v.connect();
    let info = tab.expect("info");
    assert_eq!(info["mode"], "doppler");
    tab.until_done();
    // A moving view: orbit and turn the velocities up so the lines shift visibly.
    tab.send(&json!({"type": "view", "name": "iso"}));
    tab.expect("camera");
    tab.send(&json!({"type": "doppler", "factors": {"velocity": 30.0}}));
    tab.expect("doppler");
    tab.until_done();
    let (x, y) = (20, 27);
    tab.send(&json!({"type": "pick", "x": x, "y": y}));
    let sp = tab.expect("spectrum");
    tab.send(&json!({"type": "save", "name": "pick"}));
    let saved = tab.expect("saved");
    command_reproduces(&saved, ".exr");
    // The CLI's pick of the same pixel with the printed command.
    let cmd = saved["command"].as_str().unwrap();
    run_command(cmd, &["--pick", &format!("{x},{y}")]);
    let exr = saved_file(&saved, ".exr");
    let csv_path = exr.with_file_name(format!(
        "{}_pick_{x}_{y}.csv",
        exr.file_stem().unwrap().to_string_lossy()
    ));
    let csv = std::fs::read_to_string(&csv_path).unwrap();
    let mut checked = 0;
    for line in sp["lines"].as_array().unwrap() {
        let Some(c) = line["centroid_nm"].as_f64() else {
            continue;
        };
        let w = line["window_nm"].as_array().unwrap();
        let (a, b) = (w[0].as_f64().unwrap(), w[1].as_f64().unwrap());
        let cli = csv_centroid(&csv, a, b);
        assert!(
            (c - cli).abs() < 1e-9,
            "{}: viewer {c} nm, CLI {cli} nm",
            line["name"]
        );
        checked += 1;
    }
    assert!(checked >= 1, "no line with flux at the pick: {sp}");
    // Doppler on (velocities x30): the H-alpha centroid is shifted from its rest wavelength.
    let ha = sp["lines"]
        .as_array()
        .unwrap()
        .iter()
        .find(|l| (l["rest_nm"].as_f64().unwrap() - 656.28).abs() < 0.1)
        .expect("the galaxy has H-alpha");
    let c = ha["centroid_nm"]
        .as_f64()
        .expect("H-alpha flux at the pick");
    assert!((c - 656.28).abs() > 0.01, "H-alpha not shifted: {c}");
}

#[test]
fn a_relativity_save_writes_the_exr_its_command_writes() {
    let v = Viewer::start(&[
        "--env", "checker", "--width", "40", "--height", "24", "--beta", "0.6",
    ]);
    let mut tab = v.connect();
    assert_eq!(tab.expect("info")["mode"], "relativity");
    tab.until_done();
    tab.send(
        &json!({"type": "relativity", "beta": 0.8, "direction": [1, 0, -1], "yaw": 30, "pitch": 10,
                     "effects": {"searchlight": false}}),
    );
    tab.expect("relativity");
    tab.until_done();
    tab.send(&json!({"type": "relativity", "beta": 1.0}));
    let e = tab.expect("error");
    assert!(
        e["message"].as_str().unwrap().contains("beta")
            || e["message"].as_str().unwrap().contains("speed"),
        "{e}"
    );
    tab.send(&json!({"type": "save"}));
    let saved = tab.expect("saved");
    command_reproduces(&saved, ".exr");
}

#[test]
fn save_never_replaces_an_input_or_a_foreign_file() {
    let v = Viewer::start(&[
        "--synth",
        "three-cubes",
        "--res",
        "12",
        "--width",
        "12",
        "--height",
        "12",
        "--spp",
        "1",
    ]);
    let saved_dir = v.dir.path().join("saved");
    std::fs::write(saved_dir.join("mine.png"), b"not the viewer's").unwrap();
    let mut tab = v.connect();
    tab.expect("info");
    tab.until_done();
    // The viewer's answer to a save under a name it must not take.
    let refused = |tab: &mut Tab, name: &str| {
        tab.send(&json!({"type": "save", "name": name}));
        let e = tab.expect("error");
        assert!(
            e["message"]
                .as_str()
                .unwrap()
                .contains("choose another name"),
            "{e}"
        );
    };
    refused(&mut tab, "mine");
    assert_eq!(
        std::fs::read(saved_dir.join("mine.png")).unwrap(),
        b"not the viewer's"
    );
    // A dangling symbolic link is a file this viewer did not write either: kept.
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(v.dir.path().join("gone.exr"), saved_dir.join("link.exr"))
            .unwrap();
        refused(&mut tab, "link");
        assert!(
            saved_dir
                .join("link.exr")
                .symlink_metadata()
                .unwrap()
                .file_type()
                .is_symlink()
        );
    }
    for bad in ["../escape", "/etc/passwd", "a/b"] {
        tab.send(&json!({"type": "save", "name": bad}));
        tab.expect("error");
    }
    assert!(!v.dir.path().join("escape.exr").exists());
    // Two saves without a name take two names.
    tab.send(&json!({"type": "save"}));
    let s1 = tab.expect("saved");
    tab.send(&json!({"type": "save"}));
    let s2 = tab.expect("saved");
    assert_ne!(s1["files"], s2["files"]);
}

fn rss_kib(pid: u32) -> u64 {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    s.lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap()
}

#[test]
fn ten_thousand_edits_do_not_grow_memory() {
    if !Path::new("/proc/self/status").exists() {
        eprintln!("SKIP: no /proc to read resident memory from");
        return;
    }
    let v = Viewer::start(&[
        "--synth",
        "three-cubes",
        "--res",
        "24",
        "--width",
        "32",
        "--height",
        "32",
        "--spp",
        "2",
    ]);
    let mut tab = v.connect();
    let info = tab.expect("info");
    tab.until_done();
    let cam = info["camera"].clone();
    let tf0 = info["channels"][0]["tf"].clone();
    let pid = v.child.id();
    let mut at = Vec::new();
    // Camera moves and transfer-function edits, alternating, sent in batches of 100 (the
    // worker applies a batch and renders once); every reply is read.
    for batch in 0..100u32 {
        for j in 0..100u32 {
            let i = batch * 100 + j;
            if i.is_multiple_of(2) {
                let dx = f64::from(i % 7) * 0.01;
                let eye = cam["eye"].as_array().unwrap();
                tab.send(&json!({"type": "camera",
                    "eye": [eye[0].as_f64().unwrap() + dx, eye[1], eye[2]],
                    "target": cam["target"], "up": cam["up"]}));
            } else {
                let mut tf = tf0.clone();
                tf["opacity"][0]["alpha"] = json!(f64::from(i % 5) * 0.1);
                tab.send(&json!({"type": "tf", "channel": 0, "tf": tf}));
            }
        }
        for j in 0..100u32 {
            tab.expect(if j.is_multiple_of(2) { "camera" } else { "tf" });
        }
        tab.frames.clear();
        if batch == 19 || batch == 99 {
            at.push(rss_kib(pid));
        }
    }
    tab.until_done();
    let growth = at[1] as i64 - at[0] as i64;
    eprintln!(
        "resident memory after 2,000 edits: {} KiB, after 10,000: {} KiB",
        at[0], at[1]
    );
    // 8,000 more edits: a leak of 1 KiB per edit would add 8 MiB.
    assert!(
        growth < 4 * 1024,
        "memory grew {growth} KiB over 8,000 edits"
    );
}

#[test]
fn the_device_can_be_switched_to_the_gpu() {
    let v = Viewer::start(&[
        "--synth",
        "three-cubes",
        "--res",
        "16",
        "--width",
        "24",
        "--height",
        "24",
        "--spp",
        "4",
    ]);
    let mut tab = v.connect();
    let info = tab.expect("info");
    tab.until_done();
    if info["devices"]["gpu"].is_null() {
        let require = std::env::var("BLUESHIFT_REQUIRE_GPU_TESTS").is_ok_and(|v| v == "1");
        assert!(
            !require,
            "BLUESHIFT_REQUIRE_GPU_TESTS=1 but the viewer found no adapter"
        );
        eprintln!("SKIP: no wgpu adapter");
        return;
    }
    tab.send(&json!({"type": "settings", "device": "gpu"}));
    assert_eq!(tab.expect("settings")["device"], "gpu");
    let done = tab.until_done();
    assert_ne!(done["device"], "cpu", "{done}");
    assert_eq!(done["spp"], 4);
    // Edits keep working on the device: a transfer function.
    let mut tf = info["channels"][1]["tf"].clone();
    tf["alpha_g"] = json!(0.5);
    tab.send(&json!({"type": "tf", "channel": 1, "tf": tf}));
    tab.expect("tf");
    tab.until_done();
    tab.send(&json!({"type": "settings", "device": "cpu"}));
    tab.expect("settings");
    assert_eq!(tab.until_done()["device"], "cpu");
}

#[test]
fn a_save_right_after_an_edit_saves_the_edited_image() {
    // The edit and the save arrive together: the save waits for the edit's render.
    let v = Viewer::start(&[
        "--synth",
        "three-cubes",
        "--res",
        "16",
        "--width",
        "24",
        "--height",
        "20",
        "--spp",
        "2",
    ]);
    let mut tab = v.connect();
    let info = tab.expect("info");
    tab.until_done();
    let cam = &info["camera"];
    let eye: Vec<f64> = cam["eye"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    tab.send(
        &json!({"type": "camera", "eye": [eye[0] - 0.9, eye[1] + 0.4, eye[2]],
                     "target": cam["target"], "up": cam["up"]}),
    );
    tab.send(&json!({"type": "save", "name": "at-once"}));
    let saved = tab.expect("saved");
    command_reproduces(&saved, ".exr");
    // A Doppler view change and a save together.
    let d = Viewer::start(&[
        "--synth",
        "galaxy",
        "--doppler",
        "--res",
        "16",
        "--width",
        "24",
        "--height",
        "24",
    ]);
    let mut tab = d.connect();
    tab.expect("info");
    tab.until_done();
    tab.send(&json!({"type": "view", "name": "-x"}));
    tab.send(&json!({"type": "save", "name": "at-once"}));
    command_reproduces(&tab.expect("saved"), ".exr");
}

#[test]
fn a_refused_setting_leaves_the_state_as_it_was() {
    let v = Viewer::start(&[
        "--synth",
        "three-cubes",
        "--res",
        "16",
        "--width",
        "16",
        "--height",
        "16",
        "--spp",
        "1",
    ]);
    let mut tab = v.connect();
    tab.expect("info");
    tab.until_done();
    for bad in [
        json!({"type": "settings", "density_scale": 1e30}),
        json!({"type": "settings", "density_scale": 5, "device": "bogus"}),
        json!({"type": "settings", "light_dir": [1, 1, 0], "width": 0}),
        json!({"type": "settings", "width": 16384, "height": 4096}),
    ] {
        tab.send(&bad);
        let e = tab.expect("error");
        assert!(!e["message"].as_str().unwrap().is_empty(), "{bad}");
    }
    tab.send(&json!({"type": "settings", "seed": 1}));
    let s = tab.expect("settings");
    assert_eq!(s["density_scale"], 1.0, "{s}");
    assert_eq!(s["light_dir"], Value::Null, "{s}");
    assert_eq!(s["width"], 16, "{s}");
    tab.until_done();
    tab.send(&json!({"type": "save", "name": "after"}));
    command_reproduces(&tab.expect("saved"), ".exr");
}

#[test]
fn a_bad_command_line_fails_before_the_url() {
    for args in [
        &["--env", "checker", "--width", "0"][..],
        &["--synth", "three-cubes", "--tonemap", "bogus"][..],
        &[
            "--synth",
            "three-cubes",
            "--width",
            "4096",
            "--height",
            "4096",
        ][..],
    ] {
        let out = Command::new(BIN)
            .arg("view")
            .args(args)
            .args(["--port", "0"])
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        assert!(
            out.stdout.is_empty(),
            "{args:?}: printed {:?}",
            String::from_utf8_lossy(&out.stdout)
        );
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
    }
}

#[test]
fn an_hdr_save_writes_the_png_its_tonemap_command_writes() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.exr");
    let out = Command::new(BIN)
        .args([
            "render",
            "--synth",
            "three-cubes",
            "--res",
            "16",
            "--tf",
            "builtin:inferno",
        ])
        .args(["--width", "40", "--height", "32", "--spp", "2", "--out"])
        .arg(&input)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v = Viewer::start(&["--hdr", input.to_str().unwrap()]);
    let mut tab = v.connect();
    assert_eq!(tab.expect("info")["mode"], "hdr");
    tab.until_done();
    for (i, msg) in [
        json!({"type": "tonemap", "operator": "drago", "params": {"bias": 0.7}, "roi": [4, 4, 20, 16]}),
        json!({"type": "tonemap", "operator": "fattal"}),
        json!({"type": "tonemap", "operator": "reinhard", "params": {"key": 0.3}}),
    ]
    .into_iter()
    .enumerate()
    {
        tab.send(&msg);
        tab.expect("tonemap");
        tab.until_done();
        tab.send(&json!({"type": "save", "name": format!("hdr{i}")}));
        command_reproduces(&tab.expect("saved"), ".png");
    }
    // A parameter `blueshift tonemap` has no flag for stays at its default.
    tab.send(
        &json!({"type": "tonemap", "operator": "fattal", "params": {"black_clip_percent": 3.0}}),
    );
    assert!(
        tab.expect("error")["message"]
            .as_str()
            .unwrap()
            .contains("no flag")
    );
}

/// Out of core (HDR VolVis 6.3): after an edit, the quarter-size preview of a `.bsv` volume
/// samples a coarser level (its pixels are four times the full image's, and the LOD rule
/// follows them), and the full render the finest; the statuses say which.
#[test]
fn an_out_of_core_preview_samples_a_coarser_level_than_the_full_render() {
    let data = tempfile::tempdir().unwrap();
    let bsv = data.path().join("t.bsv");
    let out = Command::new(BIN)
        .args(["synth", "turbulence"])
        .arg(&bsv)
        .args(["--res", "128", "--brick", "16"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v = Viewer::start(&[
        "--volume",
        bsv.to_str().unwrap(),
        "--tf",
        "builtin:viridis",
        "--width",
        "128",
        "--height",
        "128",
        "--spp",
        "2",
    ]);
    let mut tab = v.connect();
    let info = tab.expect("info");
    let first = tab.until_done();
    assert_eq!(first["lod_level"], 0, "{first}");
    assert_eq!(first["lod_levels"], 4, "{first}");
    let cam = &info["camera"];
    tab.send(
        &json!({"type": "camera", "eye": cam["eye"], "target": cam["target"],
                     "up": cam["up"], "fov": 30.0}),
    );
    tab.expect("camera");
    let mut preview_levels = Vec::new();
    let done = loop {
        let s = tab.expect("status");
        if s["done"] == true {
            break s;
        }
        if s["preview"] == true {
            preview_levels.push(s["lod_level"].as_u64().unwrap());
            assert_eq!(s["target_spp"], 1, "{s}");
        }
    };
    assert!(!preview_levels.is_empty(), "no preview status");
    // 32 x 32 preview pixels over a 128^3 volume framed in the view: several voxels each.
    for &l in &preview_levels {
        assert!((1..4).contains(&l), "preview level {l}");
    }
    assert_eq!(done["lod_level"], 0, "{done}");
    assert_eq!(done["spp"], 2);
}
