//! The status socket: a Unix stream socket speaking the [status protocol](super::protocol), one JSON
//! object per line each way.
//!
//! The pipeline plugs in through [`StatusSource`] (answers to requests) and [`Publisher`]
//! (events and fused frames for watchers). Every connection is its own task; none of them can
//! stall the pipeline or each other: replies that cannot be written within the write timeout,
//! and watchers that fall behind the stream, are dropped. Shutdown follows mini-redis: a
//! broadcast every task listens to, and completion when the last task's sender drops.

use std::future::Future;
use std::io;
use std::os::unix::fs::{FileTypeExt, MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::unix::OwnedWriteHalf;
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::{Semaphore, broadcast, mpsc};

use super::lines::{Frame as LineFrame, LineFramer};
use super::protocol::{
    self, Event, EventKind, Frame, MAX_LINE_BYTES, Message, Poses, Request, Saved, Status, Survey,
    Version, Watch,
};

/// How long a reply may take to be taken by a client before the client is dropped.
pub const DEFAULT_WRITE_TIMEOUT: Duration = Duration::from_secs(5);
/// A client must send its first request within this long of the banner, or it is told so
/// and closed: silent connections would otherwise hold the `max_clients` slots, and the
/// operator's `scanfuse status` would be refused. A client that has asked once (a `watch`
/// above all) stays as long as it likes.
pub const FIRST_REQUEST_WITHIN: Duration = Duration::from_secs(5);
/// Pause after a failed accept (e.g. out of file descriptors) before trying again.
const ACCEPT_BACKOFF: Duration = Duration::from_millis(100);
/// Bytes read from a client at a time.
const READ_CHUNK: usize = 8 * 1024;

/// What the socket asks of the pipeline. `status` and `poses` must be cheap snapshots (they
/// run on the connection's task); `reregister` and `save` may block and run on a blocking
/// thread.
pub trait StatusSource: Send + Sync + 'static {
    fn status(&self) -> Status;
    fn poses(&self) -> Poses;
    /// Queues a re-registration of `sensor`; the reply says what will happen.
    fn reregister(&self, sensor: &str) -> Result<String, Refused>;
    /// Writes poses and map files now.
    fn save(&self) -> Result<Saved, Refused>;
    /// Sets (`Some`) or clears (`None`) the survey of `sensor` set by hand, and re-solves the
    /// site around it. A source that cannot does not have to.
    fn survey(&self, sensor: &str, survey: Option<SurveyRequest>) -> Result<Survey, Refused> {
        let _ = survey;
        Err(Refused(format!(
            "this daemon cannot place {sensor} by hand; set survey = {{…}} in the config instead"
        )))
    }
    /// Aligns the site to the building drawing now, from `pairs` (`--pairs`' syntax) or
    /// automatically; the poses with the alignment found.
    fn align(&self, pairs: Option<&str>) -> Result<Poses, Refused> {
        let _ = pairs;
        Err(Refused(
            "this daemon cannot align to a drawing; use scanfuse align".into(),
        ))
    }
}

/// A `survey` request's pose, as sent (degrees, sigmas filled in with the defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurveyRequest {
    pub x_m: f64,
    pub y_m: f64,
    pub yaw_deg: f64,
    pub sigma_xy_m: f64,
    pub sigma_yaw_deg: f64,
}

/// The reply to every request but `watch` (whose stream belongs to the transport): the one
/// protocol both the status socket and the page's WebSocket speak. Requests that may block
/// run on a blocking thread.
pub async fn answer_request<S: StatusSource + ?Sized>(
    source: &Arc<S>,
    request: Request,
) -> Message {
    let blocking = |f: Box<dyn FnOnce() -> Message + Send>, what: &'static str| async move {
        match tokio::task::spawn_blocking(f).await {
            Ok(m) => m,
            Err(e) => Message::error(format!(
                "{what} failed inside the daemon ({e}); see its log"
            )),
        }
    };
    match request {
        Request::Status {} => Message::Status(source.status()),
        Request::Poses {} => Message::Poses(source.poses()),
        Request::Watch { .. } => Message::error(
            "watch is answered by the connection itself; send it on the status socket or the page's WebSocket",
        ),
        Request::Reregister { sensor } => {
            let source = Arc::clone(source);
            let f = move || match source.reregister(&sensor) {
                Ok(message) => Message::Reregister(protocol::Reregister { sensor, message }),
                Err(refused) => Message::error(refused.0),
            };
            blocking(Box::new(f), "re-registration").await
        }
        Request::Save {} => {
            let source = Arc::clone(source);
            let f = move || match source.save() {
                Ok(saved) => Message::Saved(saved),
                Err(refused) => Message::error(refused.0),
            };
            blocking(Box::new(f), "saving").await
        }
        Request::Survey {
            sensor,
            x_m,
            y_m,
            yaw_deg,
            sigma_xy_m,
            sigma_yaw_deg,
        } => {
            let source = Arc::clone(source);
            let request = SurveyRequest {
                x_m,
                y_m,
                yaw_deg,
                sigma_xy_m: sigma_xy_m.unwrap_or(protocol::DEFAULT_SURVEY_SIGMA_XY_M),
                sigma_yaw_deg: sigma_yaw_deg.unwrap_or(protocol::DEFAULT_SURVEY_SIGMA_YAW_DEG),
            };
            let f = move || match source.survey(&sensor, Some(request)) {
                Ok(reply) => Message::Survey(reply),
                Err(refused) => Message::error(refused.0),
            };
            blocking(Box::new(f), "placing the sensor").await
        }
        Request::Unsurvey { sensor } => {
            let source = Arc::clone(source);
            let f = move || match source.survey(&sensor, None) {
                Ok(reply) => Message::Survey(reply),
                Err(refused) => Message::error(refused.0),
            };
            blocking(Box::new(f), "clearing the survey").await
        }
        Request::Align { pairs } => {
            let source = Arc::clone(source);
            let f = move || match source.align(pairs.as_deref()) {
                Ok(poses) => Message::Poses(poses),
                Err(refused) => Message::error(refused.0),
            };
            blocking(Box::new(f), "aligning to the drawing").await
        }
    }
}

/// The pipeline declined a request; the sentence goes to the client as an ERROR.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct Refused(pub String);

/// The socket could not be set up.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SocketError {
    #[error(
        "another scanfuse is already serving {}; stop it first (systemctl stop scanfuse) or configure another socket path",
        path.display()
    )]
    AlreadyRunning { path: PathBuf },
    #[error(
        "{} exists and is not a socket; remove it or configure another socket path",
        path.display()
    )]
    NotASocket { path: PathBuf },
    #[error("cannot bind the status socket {}: {source}", path.display())]
    Bind { path: PathBuf, source: io::Error },
    #[error("cannot set the mode of {} to {mode:04o}: {source}", path.display())]
    Mode {
        path: PathBuf,
        mode: u32,
        source: io::Error,
    },
}

/// Settings of one server.
#[derive(Debug, Clone, Copy)]
pub struct ServerOptions {
    /// Permission bits of the socket file.
    pub socket_mode: u32,
    /// Clients served at once; the next one gets an ERROR and is closed.
    pub max_clients: usize,
    /// A client that takes no bytes for this long is dropped.
    pub write_timeout: Duration,
    /// A client that sends no request for this long after the banner is dropped
    /// ([`FIRST_REQUEST_WITHIN`]).
    pub first_request_within: Duration,
}

impl ServerOptions {
    /// The site file's socket settings (`[site] socket_mode`, `max_clients`).
    pub fn of(site: &super::config::SiteConfig) -> ServerOptions {
        ServerOptions {
            socket_mode: site.socket_mode,
            max_clients: site.max_clients,
            ..ServerOptions::default()
        }
    }
}

impl Default for ServerOptions {
    fn default() -> Self {
        ServerOptions {
            socket_mode: super::config::DEFAULT_SOCKET_MODE,
            max_clients: super::config::DEFAULT_MAX_CLIENTS,
            write_timeout: DEFAULT_WRITE_TIMEOUT,
            first_request_within: FIRST_REQUEST_WITHIN,
        }
    }
}

/// Sends events and fused frames to every watcher. Each item is serialized once; sending
/// never waits: a watcher that falls `backlog` items behind is dropped by its own task.
#[derive(Debug, Clone)]
pub struct Publisher {
    events: broadcast::Sender<Arc<str>>,
    frames: broadcast::Sender<Arc<str>>,
    /// Tracking output (`TRACKS`, `ZONES`, `CROSSING`), typed: the socket encodes it for its
    /// watchers, other outputs (OSC, MQTT, the page) read the fields.
    people: broadcast::Sender<Arc<Message>>,
}

impl Publisher {
    /// A publisher whose watchers may fall `backlog` items behind per stream.
    pub fn new(backlog: usize) -> Publisher {
        Publisher {
            events: broadcast::channel(backlog.max(1)).0,
            frames: broadcast::channel(backlog.max(1)).0,
            people: broadcast::channel(backlog.max(1)).0,
        }
    }

    /// Publishes an event to `status` watchers.
    pub fn event(&self, event: Event) {
        let line = format!("{}\n", Message::Event(event).to_line());
        // An error only means nobody is watching.
        let _ = self.events.send(line.into());
    }

    /// Builds and publishes an event stamped now.
    pub fn announce(&self, kind: EventKind, sensor: Option<&str>, message: impl Into<String>) {
        self.event(Event::now(kind, sensor, message));
    }

    /// Publishes a fused frame to `map` watchers; skips the encoding when nobody watches.
    pub fn frame(&self, frame: Frame) {
        if self.frames.receiver_count() == 0 {
            return;
        }
        let line = format!("{}\n", Message::Frame(frame).to_line());
        let _ = self.frames.send(line.into());
    }

    /// Publishes tracking output (`Message::Tracks`, `Zones` or `Crossing`) to every
    /// output that subscribed; a no-op when none did.
    pub fn people(&self, message: Message) {
        if self.people.receiver_count() == 0 {
            return;
        }
        let _ = self.people.send(Arc::new(message));
    }

    /// A stream of tracking output, as [`people`](Publisher::people) publishes it.
    pub fn subscribe_people(&self) -> broadcast::Receiver<Arc<Message>> {
        self.people.subscribe()
    }

    /// A stream of every event line (as a `watch` client with `status` gets them), for
    /// another transport such as the page.
    pub fn subscribe_events(&self) -> broadcast::Receiver<Arc<str>> {
        self.events.subscribe()
    }

    /// A stream of every fused-frame line (as a `watch` client with `map` gets them); while
    /// subscribed, frames are encoded.
    pub fn subscribe_frames(&self) -> broadcast::Receiver<Arc<str>> {
        self.frames.subscribe()
    }

    /// Clients currently watching events.
    pub fn event_watchers(&self) -> usize {
        self.events.receiver_count()
    }

    /// Outputs currently subscribed to the people stream (socket watchers, OSC/MQTT, pages).
    pub fn people_watchers(&self) -> usize {
        self.people.receiver_count()
    }

    /// Clients currently watching frames.
    pub fn frame_watchers(&self) -> usize {
        self.frames.receiver_count()
    }
}

/// A name next to `path` to bind before renaming into place: short (socket paths are limited
/// to 107 bytes) and this process's own.
fn temp_socket_path(path: &Path) -> PathBuf {
    path.with_file_name(format!(".sf{}.tmp", std::process::id()))
}

/// A bound status socket, ready to [`run`](StatusServer::run).
pub struct StatusServer<S> {
    listener: UnixListener,
    path: PathBuf,
    /// Device and inode of the socket file we made, so cleanup never removes another's.
    identity: (u64, u64),
    source: Arc<S>,
    publisher: Publisher,
    options: ServerOptions,
}

impl<S: StatusSource> StatusServer<S> {
    /// Binds `path` (inside a tokio runtime). A leftover socket file nobody listens on is
    /// removed; a live one means another daemon runs, and binding is refused.
    pub fn bind(
        path: &Path,
        source: Arc<S>,
        publisher: Publisher,
        options: ServerOptions,
    ) -> Result<StatusServer<S>, SocketError> {
        let bind_err = |source| SocketError::Bind {
            path: path.to_path_buf(),
            source,
        };
        remove_stale_socket(path)?;
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).map_err(bind_err)?;
        }
        // Bound under a temporary name, given its mode, then renamed into place: the socket
        // never appears at `path` with the umask's mode.
        let temp = temp_socket_path(path);
        let _ = std::fs::remove_file(&temp);
        let listener = UnixListener::bind(&temp).map_err(bind_err)?;
        if let Err(source) =
            std::fs::set_permissions(&temp, std::fs::Permissions::from_mode(options.socket_mode))
        {
            let _ = std::fs::remove_file(&temp);
            return Err(SocketError::Mode {
                path: path.to_path_buf(),
                mode: options.socket_mode,
                source,
            });
        }
        if let Err(source) = std::fs::rename(&temp, path) {
            let _ = std::fs::remove_file(&temp);
            return Err(bind_err(source));
        }
        let meta = std::fs::symlink_metadata(path).map_err(bind_err)?;
        Ok(StatusServer {
            listener,
            path: path.to_path_buf(),
            identity: (meta.dev(), meta.ino()),
            source,
            publisher: publisher.clone(),
            options,
        })
    }

    /// The socket's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Serves clients until `shutdown` resolves, then closes every connection, waits for
    /// their tasks and removes the socket file.
    pub async fn run(self, shutdown: impl Future<Output = ()>) {
        let (notify_shutdown, _) = broadcast::channel::<()>(1);
        let (complete_tx, mut complete_rx) = mpsc::channel::<()>(1);
        let limit = Arc::new(Semaphore::new(self.options.max_clients));
        tokio::select! {
            _ = self.accept_loop(&limit, &notify_shutdown, &complete_tx) => {}
            _ = shutdown => {}
        }
        drop(notify_shutdown);
        drop(complete_tx);
        // Resolves once every connection task has dropped its sender.
        let _ = complete_rx.recv().await;
        if let Ok(meta) = std::fs::symlink_metadata(&self.path)
            && (meta.dev(), meta.ino()) == self.identity
        {
            let _ = std::fs::remove_file(&self.path);
        }
    }

    async fn accept_loop(
        &self,
        limit: &Arc<Semaphore>,
        notify_shutdown: &broadcast::Sender<()>,
        complete_tx: &mpsc::Sender<()>,
    ) {
        loop {
            let stream = match self.listener.accept().await {
                Ok((stream, _)) => stream,
                Err(e) => {
                    tracing::warn!("status socket: accept failed: {e}");
                    tokio::time::sleep(ACCEPT_BACKOFF).await;
                    continue;
                }
            };
            let complete = complete_tx.clone();
            let write_timeout = self.options.write_timeout;
            let Ok(permit) = Arc::clone(limit).try_acquire_owned() else {
                let max = self.options.max_clients;
                tokio::spawn(async move {
                    let (_, mut writer) = stream.into_split();
                    let message = Message::error(format!(
                        "too many clients: this daemon serves at most {max} at once (site.max_clients); close another client or raise the limit"
                    ));
                    let _ = write_line(&mut writer, &message.to_line(), write_timeout).await;
                    drop(complete);
                });
                continue;
            };
            let connection = Connection {
                source: Arc::clone(&self.source),
                publisher: self.publisher.clone(),
                shutdown: notify_shutdown.subscribe(),
                write_timeout,
                first_request_within: self.options.first_request_within,
            };
            tokio::spawn(async move {
                if let Err(e) = connection.serve(stream).await {
                    tracing::debug!("status client dropped: {e}");
                }
                drop(permit);
                drop(complete);
            });
        }
    }
}

/// Removes a socket file nobody listens on; refuses a live one or a non-socket.
fn remove_stale_socket(path: &Path) -> Result<(), SocketError> {
    let bind_err = |source| SocketError::Bind {
        path: path.to_path_buf(),
        source,
    };
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(bind_err(e)),
        Ok(meta) if !meta.file_type().is_socket() => Err(SocketError::NotASocket {
            path: path.to_path_buf(),
        }),
        Ok(_) => match std::os::unix::net::UnixStream::connect(path) {
            Ok(_) => Err(SocketError::AlreadyRunning {
                path: path.to_path_buf(),
            }),
            Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => {
                tracing::info!("removing stale socket {}", path.display());
                std::fs::remove_file(path).map_err(bind_err)
            }
            Err(e) => Err(bind_err(e)),
        },
    }
}

/// Why a connection ended early.
#[derive(Debug, thiserror::Error)]
enum ConnectionEnd {
    #[error("client did not take a reply within {0:?}")]
    WriteTimeout(Duration),
    #[error("watcher fell {0} messages behind")]
    Lagged(u64),
    #[error("client sent no request within {} of the banner", crate::human::duration(*.0))]
    Silent(Duration),
    #[error(transparent)]
    Io(#[from] io::Error),
}

async fn write_line(
    writer: &mut OwnedWriteHalf,
    line: &str,
    timeout: Duration,
) -> Result<(), ConnectionEnd> {
    let write = async {
        writer.write_all(line.as_bytes()).await?;
        if !line.ends_with('\n') {
            writer.write_all(b"\n").await?;
        }
        Ok::<(), io::Error>(())
    };
    match tokio::time::timeout(timeout, write).await {
        Ok(result) => Ok(result?),
        Err(_) => Err(ConnectionEnd::WriteTimeout(timeout)),
    }
}

/// Most bytes one write of a watcher's stream gathers.
const BATCH_BYTES: usize = 1 << 20;

/// Appends the lines already waiting on `rx` (each ended by a newline) to `out`, up to
/// [`BATCH_BYTES`]; a lag is handed back, as `recv` would have.
fn drain_ready(
    rx: &mut Option<broadcast::Receiver<Arc<str>>>,
    out: &mut String,
) -> Result<(), broadcast::error::RecvError> {
    let Some(rx) = rx else {
        return Ok(());
    };
    while out.len() < BATCH_BYTES {
        if !out.is_empty() && !out.ends_with('\n') {
            out.push('\n');
        }
        match rx.try_recv() {
            Ok(line) => out.push_str(&line),
            Err(broadcast::error::TryRecvError::Lagged(n)) => {
                return Err(broadcast::error::RecvError::Lagged(n));
            }
            Err(_) => break,
        }
    }
    Ok(())
}

/// Receives from the people stream as protocol lines, or waits forever when not subscribed.
async fn next_people(
    rx: &mut Option<broadcast::Receiver<Arc<Message>>>,
) -> Result<Arc<str>, broadcast::error::RecvError> {
    match rx {
        Some(rx) => rx.recv().await.map(|m| Arc::from(m.to_line())),
        None => std::future::pending().await,
    }
}

/// Receives from a watch stream, or waits forever when not subscribed.
async fn next_item(
    rx: &mut Option<broadcast::Receiver<Arc<str>>>,
) -> Result<Arc<str>, broadcast::error::RecvError> {
    match rx {
        Some(rx) => rx.recv().await,
        None => std::future::pending().await,
    }
}

struct Connection<S> {
    source: Arc<S>,
    publisher: Publisher,
    shutdown: broadcast::Receiver<()>,
    write_timeout: Duration,
    first_request_within: Duration,
}

impl<S: StatusSource> Connection<S> {
    async fn serve(mut self, stream: UnixStream) -> Result<(), ConnectionEnd> {
        let (mut reader, mut writer) = stream.into_split();
        let timeout = self.write_timeout;
        write_line(
            &mut writer,
            &Message::Version(Version::current()).to_line(),
            timeout,
        )
        .await?;
        let mut framer = LineFramer::new(MAX_LINE_BYTES);
        let mut buf = vec![0u8; READ_CHUNK];
        let mut events: Option<broadcast::Receiver<Arc<str>>> = None;
        let mut frames: Option<broadcast::Receiver<Arc<str>>> = None;
        let mut people: Option<broadcast::Receiver<Arc<Message>>> = None;
        // False once the client has shut its sending side: a watcher may still be listening
        // (`echo '{"cmd":"watch"}' | socat - UNIX:…`), so the stream goes on until a write fails.
        let mut reading = true;
        // Until the first request, the client holds its slot on probation.
        let first_request_due = tokio::time::sleep(self.first_request_within);
        tokio::pin!(first_request_due);
        let mut asked = false;
        loop {
            let item = tokio::select! {
                _ = self.shutdown.recv() => return Ok(()),
                () = &mut first_request_due, if !asked => {
                    let limit = self.first_request_within;
                    let goodbye = Message::error(format!(
                        "no request within {} of connecting, so this connection was closed to keep its place for others; send a request such as {{\"cmd\":\"status\"}} right after the banner (a \"watch\" keeps the connection open)",
                        crate::human::duration(limit)
                    ));
                    // Best effort and never blocking: a client that reads nothing may not have
                    // room for it, and waiting on it is what this guards against.
                    let _ = writer.try_write(format!("{}\n", goodbye.to_line()).as_bytes());
                    return Err(ConnectionEnd::Silent(limit));
                }
                read = reader.read(&mut buf), if reading => {
                    let n = read?;
                    if n == 0 {
                        if events.is_none() && frames.is_none() && people.is_none() {
                            return Ok(());
                        }
                        reading = false;
                        continue;
                    }
                    for frame in framer.push(buf.get(..n).unwrap_or_default()) {
                        let reply = match frame {
                            LineFrame::Line(line) if line.iter().all(u8::is_ascii_whitespace) => continue,
                            LineFrame::Line(line) => {
                                asked = true;
                                self.answer(&line, &mut events, &mut frames, &mut people).await
                            }
                            LineFrame::TooLong { .. } => {
                                asked = true;
                                Message::error(format!(
                                    "request line longer than {MAX_LINE_BYTES} bytes; it was discarded. Send one request per line, e.g. {{\"cmd\":\"status\"}}"
                                ))
                            }
                        };
                        write_line(&mut writer, &reply.to_line(), timeout).await?;
                    }
                    continue;
                }
                item = next_item(&mut events) => item,
                item = next_item(&mut frames) => item,
                item = next_people(&mut people) => item,
            };
            // What else is already waiting goes out in the same write: at 100 sensors a `map`
            // watcher is sent ~3 000 frames a second, more than one write and wake-up each
            // keeps up with on a busy machine.
            let item = item.and_then(|line| {
                let mut batch = String::from(&*line);
                drain_ready(&mut frames, &mut batch)?;
                drain_ready(&mut events, &mut batch)?;
                Ok(batch)
            });
            match item {
                Ok(line) => write_line(&mut writer, &line, timeout).await?,
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    let goodbye = Message::error(format!(
                        "you fell {n} messages behind the stream and were dropped; read continuously, or watch without \"map\" to receive less"
                    ));
                    // Best effort: a client this slow may not take even this.
                    let _ = write_line(&mut writer, &goodbye.to_line(), timeout).await;
                    return Err(ConnectionEnd::Lagged(n));
                }
                // The publisher is gone: the daemon is shutting down.
                Err(broadcast::error::RecvError::Closed) => return Ok(()),
            }
        }
    }

    /// The reply to one request line; `watch` (un)subscribes the streams.
    async fn answer(
        &self,
        line: &[u8],
        events: &mut Option<broadcast::Receiver<Arc<str>>>,
        frames: &mut Option<broadcast::Receiver<Arc<str>>>,
        people: &mut Option<broadcast::Receiver<Arc<Message>>>,
    ) -> Message {
        let request = match protocol::parse_request(line) {
            Ok(r) => r,
            Err(message) => return Message::error(message),
        };
        match request {
            Request::Watch {
                status,
                map,
                tracks,
            } => {
                let want = Watch {
                    status: status.unwrap_or(true),
                    map: map.unwrap_or(false),
                    tracks: tracks.unwrap_or(false),
                };
                *events = match (want.status, events.take()) {
                    (true, Some(rx)) => Some(rx),
                    (true, None) => Some(self.publisher.events.subscribe()),
                    (false, _) => None,
                };
                *frames = match (want.map, frames.take()) {
                    (true, Some(rx)) => Some(rx),
                    (true, None) => Some(self.publisher.frames.subscribe()),
                    (false, _) => None,
                };
                *people = match (want.tracks, people.take()) {
                    (true, Some(rx)) => Some(rx),
                    (true, None) => Some(self.publisher.people.subscribe()),
                    (false, _) => None,
                };
                Message::Watch(want)
            }
            other => answer_request(&self.source, other).await,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lines waiting on a stream go out together, each on its own line; a watcher that fell
    /// behind still hears of it (the lag is not swallowed by the batching).
    #[test]
    fn waiting_lines_are_batched_and_a_lag_is_still_reported() {
        let (tx, rx) = broadcast::channel::<Arc<str>>(4);
        let mut rx = Some(rx);
        tx.send(Arc::from("b\n")).unwrap();
        tx.send(Arc::from("c")).unwrap();
        let mut batch = String::from("a\n");
        drain_ready(&mut rx, &mut batch).unwrap();
        assert_eq!(batch, "a\nb\nc\n");
        let mut none = None;
        drain_ready(&mut none, &mut batch).unwrap();
        assert_eq!(batch, "a\nb\nc\n");
        for k in 0..6 {
            tx.send(Arc::from(format!("{k}\n"))).unwrap();
        }
        let mut batch = String::new();
        assert_eq!(
            drain_ready(&mut rx, &mut batch),
            Err(broadcast::error::RecvError::Lagged(2))
        );
    }
}
