//! The page's HTTP and WebSocket server: `GET /` is the page, `GET /ws` its WebSocket.
//!
//! Who may connect, checked on every request before anything else:
//! - `Host` must be the address served (on loopback: a loopback address or `localhost` with
//!   the port served), so a page elsewhere cannot reach a loopback daemon through a visitor's
//!   browser by DNS rebinding: 403 otherwise;
//! - on a listener that is not loopback, the token (`Authorization: Bearer …`, the
//!   `scanfuse_token` cookie the page sets, or `?token=…`) from every client, loopback ones
//!   too: 401 otherwise;
//! - a WebSocket upgrade (the only way to change anything) whose `Origin` is not this page's
//!   own is refused: 403;
//! - only `GET` (and `HEAD`): 405 otherwise.
//!
//! And how much: `max_clients` pages at once (503 for the next), request messages of at
//! most [`MAX_LINE_BYTES`], and a page that does not take a message within
//! [`WRITE_TIMEOUT`] is dropped (the page reconnects); one that falls `send_queue` messages
//! behind skips to the latest state on the same connection, so a request it sent is answered.

use std::io;
use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::extract::ws::{Message as WsMessage, Utf8Bytes, WebSocket, WebSocketUpgrade};
use axum::extract::{ConnectInfo, FromRequestParts, State};
use axum::http::{HeaderMap, HeaderValue, Method, Request, Response, StatusCode, header};
use axum::response::IntoResponse;
use tokio::net::TcpListener;
use tokio::sync::{OwnedSemaphorePermit, Semaphore, broadcast, watch};

use super::bridge::{Hub, PageSource};
use super::page;
use crate::daemon::config::WebConfig;
use crate::daemon::protocol::{self, EventKind, MAX_LINE_BYTES, Message, Request as Cmd, Version};
use crate::daemon::socket::{Publisher, answer_request};

/// A page that takes no message for this long is dropped.
pub const WRITE_TIMEOUT: Duration = Duration::from_secs(5);
/// The cookie the page is given when opened with `?token=…`.
const TOKEN_COOKIE: &str = "scanfuse_token";

/// The page could not be served.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum WebError {
    #[error(
        "cannot serve the page on {addr}: the port is taken by another program; choose another [web] listen, or listen = \"\" for no page"
    )]
    PortTaken { addr: SocketAddr },
    #[error("cannot serve the page on {addr}: {source}")]
    Bind { addr: SocketAddr, source: io::Error },
    #[error("cannot use the page's token file {}: {message}", path.display())]
    Token { path: PathBuf, message: String },
}

/// A bound page server, ready to [`run`](WebServer::run).
pub struct WebServer {
    listener: TcpListener,
    local: SocketAddr,
    token: Option<Arc<str>>,
    config: WebConfig,
}

impl WebServer {
    /// Binds `config.listen` (inside a tokio runtime) and reads the token; `None` when the
    /// page is off.
    pub async fn bind(config: &WebConfig) -> Result<Option<WebServer>, WebError> {
        let Some(addr) = config.listen else {
            return Ok(None);
        };
        let token = match &config.token_file {
            Some(path) => {
                crate::daemon::config::check_token_file(path).map_err(|message| {
                    WebError::Token {
                        path: path.clone(),
                        message,
                    }
                })?;
                let text = std::fs::read_to_string(path).map_err(|e| WebError::Token {
                    path: path.clone(),
                    message: e.to_string(),
                })?;
                Some(Arc::from(text.trim()))
            }
            None => None,
        };
        if token.is_none() && !addr.ip().is_loopback() {
            return Err(WebError::Token {
                path: PathBuf::new(),
                message: format!(
                    "{addr} is not loopback, and a page reachable from elsewhere needs [web] token_file"
                ),
            });
        }
        let listener = TcpListener::bind(addr).await.map_err(|source| {
            if source.kind() == io::ErrorKind::AddrInUse {
                WebError::PortTaken { addr }
            } else {
                WebError::Bind { addr, source }
            }
        })?;
        let local = listener
            .local_addr()
            .map_err(|source| WebError::Bind { addr, source })?;
        Ok(Some(WebServer {
            listener,
            local,
            token,
            config: config.clone(),
        }))
    }

    /// The address bound (the port is known even for `:0`).
    pub fn local_addr(&self) -> SocketAddr {
        self.local
    }

    /// Where a person opens the page.
    pub fn url(&self) -> String {
        let shown = if self.local.ip().is_unspecified() {
            SocketAddr::new(IpAddr::from([127, 0, 0, 1]), self.local.port())
        } else {
            self.local
        };
        match self.token {
            Some(_) => format!(
                "http://{shown}/?token=… (the secret in {})",
                self.config
                    .token_file
                    .as_ref()
                    .map_or(String::new(), |p| p.display().to_string())
            ),
            None => format!("http://{shown}/"),
        }
    }

    /// Serves pages until `stop` turns true, then closes every page.
    pub async fn run(
        self,
        source: Arc<dyn PageSource>,
        publisher: Publisher,
        stop: watch::Receiver<bool>,
    ) {
        let hub = Hub::new(self.config.send_queue, self.config.frames_per_s);
        let shared = Arc::new(Shared {
            source: Arc::clone(&source),
            hub: Arc::clone(&hub),
            token: self.token,
            listen_ip: self.local.ip(),
            port: self.local.port(),
            hostnames: hostnames(),
            limit: Arc::new(Semaphore::new(self.config.max_clients)),
            stop: stop.clone(),
        });
        let mut hub_stop = stop.clone();
        tokio::spawn(hub.run(source, publisher, async move {
            let _ = hub_stop.wait_for(|s| *s).await;
        }));
        let app = Router::new().fallback(handle).with_state(shared);
        let mut server_stop = stop;
        let served = axum::serve(
            self.listener,
            app.into_make_service_with_connect_info::<SocketAddr>(),
        )
        .with_graceful_shutdown(async move {
            let _ = server_stop.wait_for(|s| *s).await;
        })
        .await;
        if let Err(e) = served {
            tracing::error!("the page server stopped: {e}");
        }
    }
}

/// The machine's own names, accepted as `Host` on a listener that is not loopback.
fn hostnames() -> Vec<String> {
    let Ok(name) = std::fs::read_to_string("/proc/sys/kernel/hostname") else {
        return Vec::new();
    };
    let name = name.trim().to_ascii_lowercase();
    if name.is_empty() {
        return Vec::new();
    }
    vec![format!("{name}.local"), name]
}

struct Shared {
    source: Arc<dyn PageSource>,
    hub: Arc<Hub>,
    token: Option<Arc<str>>,
    listen_ip: IpAddr,
    port: u16,
    hostnames: Vec<String>,
    limit: Arc<Semaphore>,
    stop: watch::Receiver<bool>,
}

/// Splits `host[:port]` (`[v6]:port` too); a missing port is 80.
fn split_host(host: &str) -> Option<(&str, u16)> {
    let (name, port) = if let Some(rest) = host.strip_prefix('[') {
        let (name, after) = rest.split_once(']')?;
        (name, after.strip_prefix(':'))
    } else {
        match host.rsplit_once(':') {
            Some((name, port)) => (name, Some(port)),
            None => (host, None),
        }
    };
    let port = match port {
        Some(p) => p.parse().ok()?,
        None => 80,
    };
    Some((name, port))
}

impl Shared {
    /// True when `Host` names the address served (see the module doc).
    fn host_ok(&self, headers: &HeaderMap) -> bool {
        let Some((name, port)) = headers
            .get(header::HOST)
            .and_then(|h| h.to_str().ok())
            .and_then(split_host)
        else {
            return false;
        };
        if port != self.port {
            return false;
        }
        let name = name.trim_end_matches('.').to_ascii_lowercase();
        let loopback_listener = self.listen_ip.is_loopback();
        if let Ok(ip) = name.parse::<IpAddr>() {
            return self.listen_ip.is_unspecified()
                || ip == self.listen_ip
                || (loopback_listener && ip.is_loopback());
        }
        if name == "localhost" {
            return loopback_listener || self.listen_ip.is_unspecified();
        }
        !loopback_listener && self.hostnames.contains(&name)
    }

    /// The token the request carries, if any (header, cookie or query).
    fn token_given(headers: &HeaderMap, query: Option<&str>) -> Vec<String> {
        let mut given = Vec::new();
        if let Some(bearer) = headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
        {
            given.push(bearer.trim().to_string());
        }
        for cookies in headers.get_all(header::COOKIE) {
            let Ok(cookies) = cookies.to_str() else {
                continue;
            };
            for c in cookies.split(';') {
                if let Some(v) = c
                    .trim()
                    .strip_prefix(TOKEN_COOKIE)
                    .and_then(|r| r.strip_prefix('='))
                {
                    given.push(percent_decode(v));
                }
            }
        }
        if let Some(q) = query {
            for pair in q.split('&') {
                if let Some(v) = pair.strip_prefix("token=") {
                    given.push(percent_decode(v));
                }
            }
        }
        given
    }

    fn authorized(&self, headers: &HeaderMap, query: Option<&str>) -> bool {
        match &self.token {
            None => true,
            Some(token) => Shared::token_given(headers, query)
                .iter()
                .any(|g| same_secret(g.as_bytes(), token.as_bytes())),
        }
    }

    /// True when a browser's `Origin` (absent for other clients) is this page's own.
    fn origin_ok(headers: &HeaderMap) -> bool {
        let Some(origin) = headers.get(header::ORIGIN) else {
            return true;
        };
        let host = headers.get(header::HOST).and_then(|h| h.to_str().ok());
        match (origin.to_str().ok(), host) {
            (Some(origin), Some(host)) => origin.eq_ignore_ascii_case(&format!("http://{host}")),
            _ => false,
        }
    }
}

/// Compares secrets in time that does not depend on where they differ.
fn same_secret(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// `%XX` decoded (a token in a URL); other bytes as they are.
fn percent_decode(s: &str) -> String {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while let Some(&b) = bytes.get(i) {
        let hex = bytes
            .get(i + 1..i + 3)
            .and_then(|h| std::str::from_utf8(h).ok())
            .and_then(|h| u8::from_str_radix(h, 16).ok());
        match (b, hex) {
            (b'%', Some(v)) => {
                out.push(v);
                i += 3;
            }
            _ => {
                out.push(b);
                i += 1;
            }
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

fn plain(status: StatusCode, text: impl Into<String>) -> Response<Body> {
    let mut r = (status, format!("{}\n", text.into())).into_response();
    r.headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    r
}

async fn handle(
    State(shared): State<Arc<Shared>>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    request: Request<Body>,
) -> Response<Body> {
    let (mut parts, _body) = request.into_parts();
    if !shared.host_ok(&parts.headers) {
        return plain(
            StatusCode::FORBIDDEN,
            format!(
                "this page is served as port {} of this machine; a request for another host name is refused (it may be DNS rebinding)",
                shared.port
            ),
        );
    }
    if !shared.authorized(&parts.headers, parts.uri.query()) {
        let mut r = plain(
            StatusCode::UNAUTHORIZED,
            "this page needs its token: open it as /?token=SECRET with the secret in [web] token_file",
        );
        r.headers_mut()
            .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
        return r;
    }
    if parts.method != Method::GET && parts.method != Method::HEAD {
        return plain(
            StatusCode::METHOD_NOT_ALLOWED,
            "only GET: the page changes things over its WebSocket",
        );
    }
    match parts.uri.path() {
        "/" | "/index.html" => {
            let mut r = Response::new(Body::from(page::HTML));
            let h = r.headers_mut();
            h.insert(
                header::CONTENT_TYPE,
                HeaderValue::from_static("text/html; charset=utf-8"),
            );
            h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
            h.insert(
                header::CONTENT_SECURITY_POLICY,
                HeaderValue::from_static(page::CONTENT_SECURITY_POLICY),
            );
            h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
            if let Some(token) = &shared.token
                && let Ok(cookie) = HeaderValue::from_str(&format!(
                    "{TOKEN_COOKIE}={token}; HttpOnly; SameSite=Strict; Path=/"
                ))
            {
                h.insert(header::SET_COOKIE, cookie);
            }
            r
        }
        "/ws" => {
            if !Shared::origin_ok(&parts.headers) {
                return plain(
                    StatusCode::FORBIDDEN,
                    "a WebSocket from a page of another origin is refused",
                );
            }
            let upgrade = match WebSocketUpgrade::from_request_parts(&mut parts, &()).await {
                Ok(u) => u,
                Err(rejection) => return rejection.into_response(),
            };
            let Ok(permit) = Arc::clone(&shared.limit).try_acquire_owned() else {
                return plain(
                    StatusCode::SERVICE_UNAVAILABLE,
                    "too many pages are open on this daemon ([web] max_clients); close one or raise the limit",
                );
            };
            upgrade
                .max_message_size(MAX_LINE_BYTES)
                .max_frame_size(MAX_LINE_BYTES)
                .on_upgrade(move |socket| session(socket, shared, peer, permit))
        }
        _ => plain(StatusCode::NOT_FOUND, "not here: the page is at /"),
    }
}

/// Why a page's session ended.
#[derive(Debug, thiserror::Error)]
enum End {
    #[error("it did not take a message within {} s", WRITE_TIMEOUT.as_secs())]
    Slow,
    #[error("{0}")]
    Closed(String),
}

async fn send(socket: &mut WebSocket, line: Utf8Bytes) -> Result<(), End> {
    match tokio::time::timeout(WRITE_TIMEOUT, socket.send(WsMessage::Text(line))).await {
        Ok(Ok(())) => Ok(()),
        Ok(Err(e)) => Err(End::Closed(e.to_string())),
        Err(_) => Err(End::Slow),
    }
}

fn line_of(message: &Message) -> Utf8Bytes {
    Utf8Bytes::from(message.to_line())
}

/// One page: the banner, the latest state, then the stream; its requests answered as the
/// status socket answers them.
async fn session(
    mut socket: WebSocket,
    shared: Arc<Shared>,
    peer: SocketAddr,
    _permit: OwnedSemaphorePermit,
) {
    let result = serve_page(&mut socket, &shared, peer).await;
    match result {
        Ok(()) => tracing::debug!("page {peer} closed"),
        Err(End::Closed(why)) => tracing::debug!("page {peer} closed: {why}"),
        Err(e) => {
            let why = format!("page client {peer} dropped: {e}; it reconnects when it can");
            tracing::warn!("{why}");
            shared.hub.tell_pages(EventKind::Disconnected, why);
            // Best effort, not waited for: a page this slow may not take even this.
            let _ = tokio::time::timeout(
                Duration::from_millis(100),
                socket.send(WsMessage::Close(None)),
            )
            .await;
        }
    }
}

async fn serve_page(socket: &mut WebSocket, shared: &Shared, peer: SocketAddr) -> Result<(), End> {
    let (mut stream, first) = shared.hub.subscribe();
    let mut stop = shared.stop.clone();
    send(socket, line_of(&Message::Version(Version::current()))).await?;
    for line in first {
        send(socket, line).await?;
    }
    loop {
        tokio::select! {
            () = async { let _ = stop.wait_for(|s| *s).await; } => {
                let _ = socket.send(WsMessage::Close(None)).await;
                return Ok(());
            }
            incoming = socket.recv() => match incoming {
                None => return Ok(()),
                Some(Err(e)) => return Err(End::Closed(e.to_string())),
                Some(Ok(WsMessage::Text(text))) => {
                    let reply = answer(shared, text.as_bytes()).await;
                    send(socket, line_of(&reply)).await?;
                }
                Some(Ok(WsMessage::Binary(_))) => {
                    let reply = Message::error(format!(
                        "send requests as JSON text, one per message, e.g. {{\"cmd\":\"poses\"}}; valid: {}",
                        protocol::COMMANDS
                    ));
                    send(socket, line_of(&reply)).await?;
                }
                Some(Ok(WsMessage::Close(_))) => return Ok(()),
                Some(Ok(_)) => {}
            },
            item = stream.recv() => match item {
                Ok(line) => send(socket, line).await?,
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    // A slow page skips ahead rather than being dropped: a request it sent
                    // meanwhile (a drag) must still be answered on this connection.
                    tracing::debug!("page {peer} fell {n} messages behind; sent it the latest state");
                    let (fresh, state) = shared.hub.resubscribe();
                    stream = fresh;
                    send(socket, line_of(&skipped(n))).await?;
                    for line in state {
                        send(socket, line).await?;
                    }
                }
                Err(broadcast::error::RecvError::Closed) => return Ok(()),
            },
        }
    }
}

/// What a page that fell `n` messages behind is told before the latest state.
fn skipped(n: u64) -> Message {
    Message::Event(protocol::Event::now(
        EventKind::Disconnected,
        None,
        format!(
            "this page fell {n} messages behind the stream (a slow link or a busy browser); \
             it skipped to the latest state: scans and events in between are not shown"
        ),
    ))
}

/// The reply to one request from a page: the status socket's, except `watch` (a page always
/// watches everything).
async fn answer(shared: &Shared, text: &[u8]) -> Message {
    match protocol::parse_request(text) {
        Err(message) => Message::error(message),
        Ok(Cmd::Watch { .. }) => Message::Watch(protocol::Watch {
            status: true,
            map: true,
            tracks: true,
        }),
        Ok(request) => answer_request(&shared.source, request).await,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn headers(pairs: &[(header::HeaderName, &str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (k, v) in pairs {
            h.append(k, HeaderValue::from_str(v).unwrap());
        }
        h
    }

    fn shared(listen: &str, token: Option<&str>) -> Shared {
        let addr: SocketAddr = listen.parse().unwrap();
        struct Nothing;
        impl crate::daemon::socket::StatusSource for Nothing {
            fn status(&self) -> protocol::Status {
                unreachable!()
            }
            fn poses(&self) -> protocol::Poses {
                unreachable!()
            }
            fn reregister(&self, _: &str) -> Result<String, crate::daemon::socket::Refused> {
                unreachable!()
            }
            fn save(&self) -> Result<protocol::Saved, crate::daemon::socket::Refused> {
                unreachable!()
            }
        }
        impl PageSource for Nothing {
            fn occupancy(&self) -> Option<crate::fuse::OccupancyGrid> {
                None
            }
            fn fields_of_view(&self) -> Vec<(String, f64, f64)> {
                Vec::new()
            }
        }
        Shared {
            source: Arc::new(Nothing),
            hub: Hub::new(4, 10.0),
            token: token.map(Arc::from),
            listen_ip: addr.ip(),
            port: addr.port(),
            hostnames: vec!["site-pc".into()],
            limit: Arc::new(Semaphore::new(1)),
            stop: watch::channel(false).1,
        }
    }

    #[test]
    fn a_loopback_page_answers_only_to_loopback_host_names() {
        let s = shared("127.0.0.1:8080", None);
        for ok in [
            "127.0.0.1:8080",
            "localhost:8080",
            "[::1]:8080",
            "LOCALHOST.:8080",
        ] {
            assert!(s.host_ok(&headers(&[(header::HOST, ok)])), "{ok}");
        }
        for bad in [
            "evil.example:8080",
            "127.0.0.1:8081",
            "192.168.1.5:8080",
            "site-pc:8080",
            "localhost",
        ] {
            assert!(!s.host_ok(&headers(&[(header::HOST, bad)])), "{bad}");
        }
        assert!(!s.host_ok(&HeaderMap::new()), "no Host at all");
    }

    #[test]
    fn a_page_on_every_interface_answers_to_addresses_and_its_own_name() {
        let s = shared("0.0.0.0:8080", Some("t"));
        for ok in ["192.168.1.5:8080", "site-pc:8080", "127.0.0.1:8080"] {
            assert!(s.host_ok(&headers(&[(header::HOST, ok)])), "{ok}");
        }
        assert!(!s.host_ok(&headers(&[(header::HOST, "evil.example:8080")])));
    }

    #[test]
    fn the_token_is_taken_from_header_cookie_or_query_and_nothing_else() {
        let s = shared("0.0.0.0:8080", Some("s3cret+/="));
        assert!(!s.authorized(&HeaderMap::new(), None));
        assert!(!s.authorized(&HeaderMap::new(), Some("token=wrong")));
        assert!(s.authorized(&HeaderMap::new(), Some("a=1&token=s3cret%2B%2F%3D")));
        assert!(s.authorized(
            &headers(&[(header::AUTHORIZATION, "Bearer s3cret+/=")]),
            None
        ));
        assert!(s.authorized(
            &headers(&[(header::COOKIE, "x=1; scanfuse_token=s3cret+/=")]),
            None
        ));
        assert!(shared("127.0.0.1:8080", None).authorized(&HeaderMap::new(), None));
    }

    #[test]
    fn a_websocket_from_another_origin_is_refused() {
        let host = (header::HOST, "127.0.0.1:8080");
        assert!(
            Shared::origin_ok(&headers(std::slice::from_ref(&host))),
            "no Origin: not a browser"
        );
        assert!(Shared::origin_ok(&headers(&[
            host.clone(),
            (header::ORIGIN, "http://127.0.0.1:8080")
        ])));
        assert!(!Shared::origin_ok(&headers(&[
            host,
            (header::ORIGIN, "http://evil.example")
        ])));
    }
}
