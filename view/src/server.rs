//! The HTTP side: binding, the token, the Host and Origin checks, the page, its assets and
//! the WebSocket of each tab.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::sync::Arc;

use axum::Router;
use axum::body::Body;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{FromRequestParts, Path as UrlPath, Request, State};
use axum::http::{StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::get;

use crate::worker::{Outgoing, Worker};
use crate::{Error, MAX_MESSAGE_BYTES, Result, Source};

/// Where and how the server listens.
#[derive(Clone, Debug)]
pub struct Config {
    /// Address to bind (default 127.0.0.1).
    pub address: IpAddr,
    /// Port (0: any free one).
    pub port: u16,
    /// Folder the `save` message writes into (created if missing).
    pub save_dir: PathBuf,
    /// The token of the URLs (default: 32 random hex digits, [`new_token`]).
    pub token: Option<String>,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            address: IpAddr::V4(Ipv4Addr::LOCALHOST),
            port: 0,
            save_dir: PathBuf::from("."),
            token: None,
        }
    }
}

/// A fresh random token: 128 bits from the operating system, as 32 lowercase hex digits.
///
/// # Errors
/// [`Error::Io`] when the system has no random source.
pub fn new_token() -> Result<String> {
    let mut b = [0u8; 16];
    getrandom::fill(&mut b)
        .map_err(|e| Error::io("cannot draw a random token", std::io::Error::other(e)))?;
    Ok(b.iter().map(|x| format!("{x:02x}")).collect())
}

/// Whether a `Host` header value names this server: the bound address, 127.0.0.1,
/// localhost or [::1], each with the bound port. Bound to an unspecified address
/// (`--bind 0.0.0.0`), any IP literal with the port is accepted too (the address the other
/// machine reached this one by; DNS rebinding needs a host name, which stays refused), but
/// never the unspecified address itself.
#[must_use]
pub fn allowed_host(host: &str, bound: SocketAddr) -> bool {
    let port = bound.port();
    if bound.ip().is_unspecified()
        && let Ok(addr) = host.parse::<SocketAddr>()
    {
        return addr.port() == port && !addr.ip().is_unspecified();
    }
    let mut ok = vec![
        format!("127.0.0.1:{port}"),
        format!("localhost:{port}"),
        format!("[::1]:{port}"),
    ];
    ok.push(match bound.ip() {
        IpAddr::V4(a) => format!("{a}:{port}"),
        IpAddr::V6(a) => format!("[{a}]:{port}"),
    });
    ok.iter().any(|h| h.eq_ignore_ascii_case(host))
}

/// Shared by every request.
struct App {
    token: String,
    bound: SocketAddr,
    source: Arc<Source>,
    save_dir: PathBuf,
    written: crate::worker::Written,
    tabs: std::sync::atomic::AtomicUsize,
}

/// Most tabs served at once (each has its own session: a copy of the scene).
pub const MAX_TABS: usize = 8;

/// A bound server, ready to [`Server::run`].
#[derive(Debug)]
pub struct Server {
    listener: std::net::TcpListener,
    bound: SocketAddr,
    token: String,
    source: Arc<Source>,
    save_dir: PathBuf,
}

impl Server {
    /// Binds the address and makes the save folder.
    ///
    /// # Errors
    /// [`Error::Io`] for an address in use or an unwritable folder; [`Error::Invalid`] for
    /// a token that is not 16-64 characters of `[0-9A-Za-z_-]`.
    pub fn bind(source: Source, config: Config) -> Result<Self> {
        let token = match config.token {
            Some(t) => t,
            None => new_token()?,
        };
        let token_ok = (16..=64).contains(&token.len())
            && token
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
        if !token_ok {
            return Err(Error::invalid(
                "token: 16 to 64 characters of A-Z, a-z, 0-9, '-' and '_'",
            ));
        }
        std::fs::create_dir_all(&config.save_dir).map_err(|e| {
            Error::io(
                format!("cannot create --save-dir {}", config.save_dir.display()),
                e,
            )
        })?;
        let save_dir = std::fs::canonicalize(&config.save_dir)
            .map_err(|e| Error::io(format!("--save-dir {}", config.save_dir.display()), e))?;
        // Refuse a source the sessions cannot be built from before printing any URL.
        drop(crate::modes::build(&source)?);
        let addr = SocketAddr::new(config.address, config.port);
        let listener = std::net::TcpListener::bind(addr)
            .map_err(|e| Error::io(format!("cannot listen on {addr}"), e))?;
        listener
            .set_nonblocking(true)
            .map_err(|e| Error::io("cannot configure the socket", e))?;
        let bound = listener
            .local_addr()
            .map_err(|e| Error::io("cannot read the bound address", e))?;
        Ok(Self {
            listener,
            bound,
            token,
            source: Arc::new(source),
            save_dir,
        })
    }

    /// The address the server listens on.
    #[must_use]
    pub fn address(&self) -> SocketAddr {
        self.bound
    }

    /// The URL of the page, with its token.
    #[must_use]
    pub fn url(&self) -> String {
        let host = match self.bound.ip() {
            IpAddr::V4(a) if a.is_unspecified() => format!("127.0.0.1:{}", self.bound.port()),
            IpAddr::V6(a) if a.is_unspecified() => format!("[::1]:{}", self.bound.port()),
            IpAddr::V4(a) => format!("{a}:{}", self.bound.port()),
            IpAddr::V6(a) => format!("[{a}]:{}", self.bound.port()),
        };
        format!("http://{host}/{}/", self.token)
    }

    /// Serves until the process is interrupted (Ctrl-C or SIGTERM).
    ///
    /// # Errors
    /// [`Error::Io`] when the runtime cannot start or the socket fails.
    pub fn run(self) -> Result<()> {
        self.serve_until(shutdown())
    }

    /// Serves on a thread of its own until [`Running::stop`] (or the handle is dropped),
    /// installing no signal handler: for a host program (a Python kernel) that keeps its
    /// own Ctrl-C.
    ///
    /// # Errors
    /// [`Error::Io`] when the thread cannot start.
    pub fn spawn(self) -> Result<Running> {
        let url = self.url();
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::Builder::new()
            .name("blueshift-view".into())
            .spawn(move || {
                self.serve_until(async move {
                    let _ = rx.await;
                })
            })
            .map_err(|e| Error::io("cannot start the server thread", e))?;
        Ok(Running {
            url,
            stop: Some(tx),
            thread: Some(thread),
        })
    }

    fn serve_until(
        self,
        stop: impl std::future::Future<Output = ()> + Send + 'static,
    ) -> Result<()> {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .map_err(|e| Error::io("cannot start the server runtime", e))?;
        rt.block_on(async move {
            let listener = tokio::net::TcpListener::from_std(self.listener)
                .map_err(|e| Error::io("cannot use the socket", e))?;
            let app = Arc::new(App {
                token: self.token,
                bound: self.bound,
                source: self.source,
                save_dir: self.save_dir,
                written: Default::default(),
                tabs: std::sync::atomic::AtomicUsize::new(0),
            });
            axum::serve(listener, router(app))
                .with_graceful_shutdown(stop)
                .await
                .map_err(|e| Error::io("server", e))
        })
    }
}

/// A server serving on its own thread ([`Server::spawn`]).
#[derive(Debug)]
pub struct Running {
    url: String,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<Result<()>>>,
}

impl Running {
    /// The URL of the page, with its token.
    #[must_use]
    pub fn url(&self) -> &str {
        &self.url
    }

    /// Whether the server still serves.
    #[must_use]
    pub fn is_running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }

    /// Stops serving (open pages lose their connection) and waits for the thread.
    ///
    /// # Errors
    /// What the server failed with, if it did.
    pub fn stop(&mut self) -> Result<()> {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        match self.thread.take().map(std::thread::JoinHandle::join) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(Error::invalid("the server thread panicked")),
            None => Ok(()),
        }
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.stop();
    }
}

async fn shutdown() {
    let ctrl_c = tokio::signal::ctrl_c();
    #[cfg(unix)]
    {
        let mut term =
            match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
                Ok(t) => t,
                Err(_) => {
                    let _ = ctrl_c.await;
                    return;
                }
            };
        tokio::select! {
            _ = ctrl_c => {},
            _ = term.recv() => {},
        }
    }
    #[cfg(not(unix))]
    {
        let _ = ctrl_c.await;
    }
}

fn router(app: Arc<App>) -> Router {
    Router::new()
        .route("/{token}/ws", get(ws))
        .route("/{token}/", get(index))
        .route("/{token}/{file}", get(asset))
        .fallback(not_found)
        .layer(middleware::from_fn_with_state(app.clone(), guard))
        .with_state(app)
}

/// Refuses a foreign `Host` (DNS rebinding) or `Origin` before anything else runs.
async fn guard(State(app): State<Arc<App>>, req: Request, next: Next) -> Response {
    if let Err(why) = headers_allowed(req.headers(), app.bound) {
        return (StatusCode::FORBIDDEN, why).into_response();
    }
    next.run(req).await
}

/// `Ok` for exactly one `Host` naming this server and at most one `Origin`, also this
/// server's; else the reason. A repeated header is refused: which one a proxy or the browser
/// acted on is unknown, and only the first was checked.
fn headers_allowed(
    headers: &axum::http::HeaderMap,
    bound: SocketAddr,
) -> std::result::Result<(), &'static str> {
    let mut hosts = headers.get_all(header::HOST).iter();
    let host = hosts.next().and_then(|h| h.to_str().ok()).unwrap_or("");
    if hosts.next().is_some() || !allowed_host(host, bound) {
        return Err("forbidden: unknown Host\n");
    }
    let mut origins = headers.get_all(header::ORIGIN).iter();
    if let Some(origin) = origins.next() {
        let ok = origin
            .to_str()
            .ok()
            .and_then(|o| o.strip_prefix("http://"))
            .is_some_and(|h| allowed_host(h, bound));
        if !ok || origins.next().is_some() {
            return Err("forbidden: foreign Origin\n");
        }
    }
    Ok(())
}

/// Compares tokens in time independent of where they differ.
fn token_matches(given: &str, want: &str) -> bool {
    let (a, b) = (given.as_bytes(), want.as_bytes());
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

async fn not_found() -> Response {
    (StatusCode::NOT_FOUND, "not found\n").into_response()
}

fn page(bytes: &'static [u8], mime: &'static str) -> Response {
    Response::builder()
        .status(StatusCode::OK)
        .header(header::CONTENT_TYPE, mime)
        .header(header::CACHE_CONTROL, "no-store")
        .header(header::X_CONTENT_TYPE_OPTIONS, "nosniff")
        .header(
            header::CONTENT_SECURITY_POLICY,
            "default-src 'self'; img-src 'self' blob: data:; connect-src 'self'; style-src 'self' 'unsafe-inline'",
        )
        .body(Body::from(bytes))
        .unwrap_or_else(|_| StatusCode::INTERNAL_SERVER_ERROR.into_response())
}

async fn index(State(app): State<Arc<App>>, UrlPath(token): UrlPath<String>) -> Response {
    if !token_matches(&token, &app.token) {
        return not_found().await;
    }
    match crate::assets::get("index.html") {
        Some((bytes, mime)) => page(bytes, mime),
        None => not_found().await,
    }
}

async fn asset(
    State(app): State<Arc<App>>,
    UrlPath((token, file)): UrlPath<(String, String)>,
) -> Response {
    if !token_matches(&token, &app.token) {
        return not_found().await;
    }
    match crate::assets::get(&file) {
        Some((bytes, mime)) => page(bytes, mime),
        None => not_found().await,
    }
}

async fn ws(
    State(app): State<Arc<App>>,
    UrlPath(token): UrlPath<String>,
    req: Request,
) -> Response {
    // A wrong token is a plain 404, whatever the request looks like.
    if !token_matches(&token, &app.token) {
        return not_found().await;
    }
    let (mut parts, _) = req.into_parts();
    let upgrade = match WebSocketUpgrade::from_request_parts(&mut parts, &()).await {
        Ok(u) => u,
        Err(e) => return e.into_response(),
    };
    let app2 = app.clone();
    upgrade
        .max_message_size(MAX_MESSAGE_BYTES)
        .max_frame_size(MAX_MESSAGE_BYTES)
        .on_upgrade(move |socket| connection(socket, app2))
}

/// One tab: its worker thread renders; this task moves messages both ways.
async fn connection(mut socket: WebSocket, app: Arc<App>) {
    use std::sync::atomic::Ordering;
    if app.tabs.fetch_add(1, Ordering::SeqCst) >= MAX_TABS {
        app.tabs.fetch_sub(1, Ordering::SeqCst);
        let msg = crate::protocol::error_json(
            &format!("this viewer serves at most {MAX_TABS} tabs at once; close one"),
            None,
        );
        let _ = socket.send(Message::Text(msg.into())).await;
        return;
    }
    serve_tab(&mut socket, &app).await;
    app.tabs.fetch_sub(1, Ordering::SeqCst);
}

async fn serve_tab(socket: &mut WebSocket, app: &App) {
    let (worker, mut text_rx, mut frame_rx) = match Worker::spawn(
        app.source.clone(),
        app.save_dir.clone(),
        app.written.clone(),
    ) {
        Ok(w) => w,
        Err(e) => {
            let msg = crate::protocol::error_json(&e.to_string(), None);
            let _ = socket.send(Message::Text(msg.into())).await;
            return;
        }
    };
    loop {
        tokio::select! {
            incoming = socket.recv() => {
                match incoming {
                    Some(Ok(Message::Text(t))) => worker.submit(t.as_str()),
                    Some(Ok(Message::Binary(_))) => {
                        let msg = crate::protocol::error_json("binary messages are not part of the protocol; send JSON text", None);
                        if socket.send(Message::Text(msg.into())).await.is_err() { break; }
                    }
                    Some(Ok(Message::Ping(_) | Message::Pong(_))) => {}
                    Some(Ok(Message::Close(_)) | Err(_)) | None => break,
                }
            }
            text = text_rx.recv() => {
                match text {
                    Some(Outgoing::Text(t)) => {
                        if socket.send(Message::Text(t.into())).await.is_err() { break; }
                    }
                    Some(Outgoing::Binary(b)) => {
                        if socket.send(Message::Binary(b.into())).await.is_err() { break; }
                    }
                    None => break,
                }
            }
            changed = frame_rx.changed() => {
                if changed.is_err() { break; }
                let frame = frame_rx.borrow_and_update().clone();
                if let Some(bytes) = frame
                    && socket.send(Message::Binary(bytes.as_ref().clone().into())).await.is_err() {
                    break;
                }
            }
        }
    }
    worker.stop();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_this_servers_names_are_hosts() {
        let lo: SocketAddr = "127.0.0.1:8765".parse().unwrap();
        for ok in [
            "127.0.0.1:8765",
            "localhost:8765",
            "LOCALHOST:8765",
            "[::1]:8765",
        ] {
            assert!(allowed_host(ok, lo), "{ok}");
        }
        for bad in [
            "127.0.0.1",
            "127.0.0.1:8766",
            "evil.example:8765",
            "localhost.:8765",
            "192.168.1.5:8765",
            "0.0.0.0:8765",
            "",
        ] {
            assert!(!allowed_host(bad, lo), "{bad}");
        }
        // Bound to every interface: IP literals of the machine are fine, names are not
        // (DNS rebinding needs one), nor the unspecified address.
        let any: SocketAddr = "0.0.0.0:8765".parse().unwrap();
        assert!(allowed_host("192.168.1.5:8765", any));
        assert!(allowed_host("localhost:8765", any));
        for bad in [
            "evil.example:8765",
            "0.0.0.0:8765",
            "[::]:8765",
            "192.168.1.5:1",
        ] {
            assert!(!allowed_host(bad, any), "{bad}");
        }
    }

    #[test]
    fn one_host_and_at_most_one_origin_of_this_server() {
        use axum::http::{HeaderMap, HeaderValue};
        let lo: SocketAddr = "127.0.0.1:8765".parse().unwrap();
        let map = |pairs: &[(header::HeaderName, &'static str)]| {
            let mut m = HeaderMap::new();
            for (k, v) in pairs {
                m.append(k.clone(), HeaderValue::from_static(v));
            }
            m
        };
        let (h, o) = (header::HOST, header::ORIGIN);
        let good = "127.0.0.1:8765";
        assert!(headers_allowed(&map(&[(h.clone(), good)]), lo).is_ok());
        assert!(
            headers_allowed(
                &map(&[(h.clone(), good), (o.clone(), "http://localhost:8765")]),
                lo
            )
            .is_ok()
        );
        for bad in [
            vec![],
            vec![(h.clone(), "evil.example:8765")],
            // The first Host is this server's, the second another's.
            vec![(h.clone(), good), (h.clone(), "evil.example:8765")],
            vec![(h.clone(), good), (h.clone(), good)],
            vec![(h.clone(), good), (o.clone(), "http://evil.example")],
            vec![
                (h.clone(), good),
                (o.clone(), "http://127.0.0.1:8765"),
                (o.clone(), "http://evil.example"),
            ],
        ] {
            assert!(headers_allowed(&map(&bad), lo).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn tokens_are_random_hex() {
        let (a, b) = (new_token().unwrap(), new_token().unwrap());
        assert_eq!(a.len(), 32);
        assert!(a.bytes().all(|c| c.is_ascii_hexdigit()));
        assert_ne!(a, b);
        assert!(token_matches(&a, &a.clone()));
        assert!(!token_matches(&a, &b));
        assert!(!token_matches(&a[..31], &a));
    }
}
