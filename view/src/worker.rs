//! One tab's worker thread: it owns the tab's engine session, applies the edits, renders
//! the preview and the refinement passes, and answers requests.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use blueshift_camera::CancelToken;
use image::RgbImage;
use serde_json::{Value, json};
use tokio::sync::{mpsc as tmpsc, watch};

use crate::modes::{self, Mode};
use crate::protocol::{self, Incoming};
use crate::{Result, Source};

/// What goes to the page besides the main frames.
#[derive(Debug)]
pub(crate) enum Outgoing {
    /// A JSON message.
    Text(String),
    /// A binary image that is not the main frame (panels, colour bars).
    Binary(Vec<u8>),
}

/// The files the server wrote, shared by the tabs.
pub(crate) type Written = Arc<Mutex<std::collections::HashSet<PathBuf>>>;

/// The newest main frame (header + PNG), or none yet.
pub(crate) type FrameSlot = Option<Arc<Vec<u8>>>;

/// The handle the connection task keeps.
pub(crate) struct Worker {
    tx: mpsc::SyncSender<Incoming>,
    cancel: CancelToken,
    text: tmpsc::Sender<Outgoing>,
}

/// Messages a tab may have waiting for its worker; more are refused with an error (the page
/// must read its replies: the worker waits for the socket, so the queues stay bounded).
const QUEUE: usize = 256;

/// What a render needs to reach the page, shared with the observers.
pub(crate) struct Ctx {
    text: tmpsc::Sender<Outgoing>,
    frame: watch::Sender<FrameSlot>,
    pub(crate) cancel: CancelToken,
    seq: AtomicU64,
    /// Messages read during a render that wait for its end.
    deferred: Mutex<VecDeque<Incoming>>,
    rx: Mutex<mpsc::Receiver<Incoming>>,
    /// Where `save` writes.
    pub(crate) save_dir: PathBuf,
    /// Files this server wrote, shared by all tabs (a named save may replace them, nothing
    /// else); held for the whole of a save, so two tabs never pick one name.
    pub(crate) written: Written,
    last_frame: Mutex<Option<Instant>>,
}

/// Least time between two streamed refinement frames (the page shows at most 30 per
/// second; the final pass is always sent).
const FRAME_INTERVAL: Duration = Duration::from_millis(33);

impl Ctx {
    /// Sends a JSON message.
    pub(crate) fn send(&self, v: &Value) {
        // Waits while the page is not reading (back-pressure instead of an unbounded queue);
        // fails only when the tab is gone.
        let _ = self.text.blocking_send(Outgoing::Text(v.to_string()));
    }

    /// Sends an `error` reply.
    pub(crate) fn error(&self, message: &str, request: Option<&str>) {
        let _ = self
            .text
            .blocking_send(Outgoing::Text(protocol::error_json(message, request)));
    }

    /// Whether a refinement frame is due now (`last` frames always are).
    pub(crate) fn frame_due(&self, last: bool) -> bool {
        let mut t = self.last_frame.lock().unwrap_or_else(|e| e.into_inner());
        let due = last || t.is_none_or(|t| t.elapsed() >= FRAME_INTERVAL);
        if due {
            *t = Some(Instant::now());
        }
        due
    }

    /// Sends an image: `kind` `frame` replaces the newest main frame; other kinds (panels,
    /// colour bars) queue like text. `extra` joins the header.
    pub(crate) fn send_image(&self, kind: &str, img: &RgbImage, extra: Value) -> Result<()> {
        let png = crate::display::png_bytes(img)?;
        let seq = self.seq.fetch_add(1, Ordering::Relaxed);
        let mut header = json!({
            "kind": kind, "seq": seq, "width": img.width(), "height": img.height(),
        });
        if let (Some(h), Value::Object(e)) = (header.as_object_mut(), extra) {
            h.extend(e);
        }
        let bytes = protocol::binary_frame(&header, &png);
        if kind == "frame" {
            let _ = self.frame.send(Some(Arc::new(bytes)));
        } else {
            let _ = self.text.blocking_send(Outgoing::Binary(bytes));
        }
        Ok(())
    }

    /// Reads the messages that arrived during a render: the ones `now` can serve are
    /// served at once (with the render's current state), the rest wait for the render's
    /// end. Called by the observers between passes.
    /// An edit among them cancels the render (it is applied after); once one message
    /// waits, every later one waits too, so replies keep the order of the requests.
    pub(crate) fn poll(&self, mut now: impl FnMut(&Incoming) -> Option<Result<()>>) {
        let rx = self.rx.lock().unwrap_or_else(|e| e.into_inner());
        loop {
            let m = match rx.try_recv() {
                Ok(m) => m,
                Err(mpsc::TryRecvError::Empty) => break,
                Err(mpsc::TryRecvError::Disconnected) => {
                    // The tab is gone: stop rendering for it.
                    self.cancel.cancel();
                    break;
                }
            };
            if m.is_edit() {
                self.cancel.cancel();
            }
            let waiting = !self
                .deferred
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .is_empty();
            let served = if waiting || m.is_edit() {
                None
            } else {
                now(&m)
            };
            match served {
                Some(Ok(())) => {}
                Some(Err(e)) => self.error(&e.to_string(), Some(m.kind())),
                None => self
                    .deferred
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .push_back(m),
            }
        }
    }
}

impl Worker {
    /// Starts a tab's worker: its own session over a copy of the source.
    pub(crate) fn spawn(
        source: Arc<Source>,
        save_dir: PathBuf,
        written: Written,
    ) -> Result<(
        Worker,
        tmpsc::Receiver<Outgoing>,
        watch::Receiver<FrameSlot>,
    )> {
        let (tx, rx) = mpsc::sync_channel(QUEUE);
        let (text_tx, text_rx) = tmpsc::channel(QUEUE);
        let (frame_tx, frame_rx) = watch::channel(None);
        let cancel = CancelToken::new();
        let ctx = Ctx {
            text: text_tx.clone(),
            frame: frame_tx,
            cancel: cancel.clone(),
            seq: AtomicU64::new(0),
            deferred: Mutex::new(VecDeque::new()),
            rx: Mutex::new(rx),
            save_dir,
            written,
            last_frame: Mutex::new(None),
        };
        std::thread::Builder::new()
            .name("blueshift-view-worker".into())
            .spawn(move || match modes::build(&source) {
                Ok(mode) => run(mode, &ctx),
                Err(e) => ctx.error(&e.to_string(), None),
            })
            .map_err(|e| crate::Error::io("cannot start a worker thread", e))?;
        Ok((
            Worker {
                tx,
                cancel,
                text: text_tx,
            },
            text_rx,
            frame_rx,
        ))
    }

    /// Hands a text message to the worker; an edit cancels the running render. A malformed
    /// message gets its error reply here and goes no further.
    pub(crate) fn submit(&self, text: &str) {
        match protocol::parse(text) {
            Ok(m) => {
                // Cancel first, then queue: the worker clears the flag only after reading.
                let edit = m.is_edit();
                let kind = m.kind();
                if edit {
                    self.cancel.cancel();
                }
                if let Err(mpsc::TrySendError::Full(_)) = self.tx.try_send(m) {
                    let msg = format!(
                        "{kind}: refused, {QUEUE} messages are already waiting; read the replies before sending more"
                    );
                    let _ = self
                        .text
                        .try_send(Outgoing::Text(protocol::error_json(&msg, Some(kind))));
                }
            }
            Err(e) => {
                let _ = self
                    .text
                    .try_send(Outgoing::Text(protocol::error_json(&e.to_string(), None)));
            }
        }
    }

    /// Stops the worker (the tab went away): the render is cancelled and the thread ends
    /// when it sees its channel closed.
    pub(crate) fn stop(self) {
        drop(self.tx);
        self.cancel.cancel();
    }
}

/// How much to render after the edits of one round.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(crate) enum Stage {
    /// Only the display mapping changed: the last HDR frame is mapped again.
    Display,
    /// The full-resolution render without a preview (cheap edits).
    Full,
    /// Quarter- (and, from 256x256, half-) resolution 1-spp previews, then the
    /// full-resolution refinement.
    Preview,
}

fn run(mut mode: Box<dyn Mode + '_>, ctx: &Ctx) {
    ctx.send(&info_with_dir(mode.as_ref(), ctx));
    let mut need = Some(Stage::Preview);
    loop {
        let mut msgs: Vec<Incoming> = ctx
            .deferred
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .drain(..)
            .collect();
        let mut closed = false;
        {
            let rx = ctx.rx.lock().unwrap_or_else(|e| e.into_inner());
            if need.is_none() && msgs.is_empty() {
                match rx.recv() {
                    Ok(m) => msgs.push(m),
                    Err(_) => return,
                }
            }
            // An edit raises the cancel flag before it is queued: clear the flag between two
            // reads, so an edit that comes later still stops the render that follows.
            for round in 0..2 {
                if round == 1 {
                    ctx.cancel.reset();
                }
                loop {
                    match rx.try_recv() {
                        Ok(m) => msgs.push(m),
                        Err(mpsc::TryRecvError::Empty) => break,
                        Err(mpsc::TryRecvError::Disconnected) => {
                            closed = true;
                            break;
                        }
                    }
                }
            }
        }
        if closed {
            return;
        }
        // Requests that follow an edit in the same batch (save, pick, ...) wait for the
        // render of that edit, so they see its result.
        let mut after: Vec<Incoming> = Vec::new();
        for m in msgs {
            let kind = m.kind();
            if matches!(m, Incoming::Cancel) {
                need = None;
                continue;
            }
            if need.is_some_and(|s| s > Stage::Display) && !m.is_edit() {
                after.push(m);
                continue;
            }
            if matches!(m, Incoming::Hello) {
                ctx.send(&info_with_dir(mode.as_ref(), ctx));
                continue;
            }
            match mode.handle(m, ctx) {
                Ok(Some(stage)) => need = need.max(Some(stage)),
                Ok(None) => {}
                Err(e) => ctx.error(&e.to_string(), Some(kind)),
            }
        }
        if let Some(stage) = need.take() {
            if stage > Stage::Display {
                // The last frame no longer shows the state: nothing may be saved from it.
                mode.invalidate();
            }
            match mode.render(stage, ctx) {
                Ok(()) => {}
                // Render again after reading what cancelled it (unless that was `cancel`).
                Err(e) if e.is_cancelled() => need = Some(stage),
                Err(e) => ctx.error(&e.to_string(), None),
            }
        }
        if !after.is_empty() {
            let mut d = ctx.deferred.lock().unwrap_or_else(|e| e.into_inner());
            for m in after.into_iter().rev() {
                d.push_front(m);
            }
        }
    }
}

/// The mode's `info` with the save folder.
pub(crate) fn info_with_dir(mode: &dyn Mode, ctx: &Ctx) -> Value {
    let mut v = mode.info();
    if let Some(o) = v.as_object_mut() {
        o.insert(
            "save_dir".into(),
            Value::String(ctx.save_dir.display().to_string()),
        );
    }
    v
}
