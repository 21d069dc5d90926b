//! Where a sensor is and how bytes get to it: `tcp://host:port` or `serial:///dev/ttyACM0`
//! (`?baud=115200`). A serial port is blocking, so two threads bridge it to an async stream.

use std::io::{Read, Write};
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

use thiserror::Error;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, DuplexStream, ReadBuf};
use tokio::net::TcpStream;

/// Default SCIP port of Ethernet units.
pub const DEFAULT_TCP_PORT: u16 = 10940;
/// USB units ignore the rate; RS-232 ones start at 19200.
pub const DEFAULT_BAUD: u32 = 115_200;

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    Tcp { host: String, port: u16 },
    Serial { path: String, baud: u32 },
}

#[derive(Debug, Error)]
#[non_exhaustive]
pub enum TransportError {
    #[error("{0:?} is not a sensor address: use tcp://HOST:PORT or serial:///dev/PATH[?baud=N]")]
    BadUri(String),
    #[error("connecting to {uri} timed out after {timeout:?}")]
    Timeout { uri: String, timeout: Duration },
    #[error("connecting to {uri}: {source}")]
    Io {
        uri: String,
        #[source]
        source: std::io::Error,
    },
    #[error("opening {path}: {source}")]
    Serial {
        path: String,
        #[source]
        source: serialport::Error,
    },
}

impl Endpoint {
    pub fn parse(uri: &str) -> Result<Endpoint, TransportError> {
        let bad = || TransportError::BadUri(uri.to_string());
        if let Some(rest) = uri.strip_prefix("tcp://") {
            let rest = rest.trim_end_matches('/');
            let (host, port) = match rest.rsplit_once(':') {
                Some((host, port)) => (host, port.parse().map_err(|_| bad())?),
                None => (rest, DEFAULT_TCP_PORT),
            };
            if host.is_empty() {
                return Err(bad());
            }
            return Ok(Endpoint::Tcp {
                host: host.to_string(),
                port,
            });
        }
        if let Some(rest) = uri.strip_prefix("serial://") {
            let (path, query) = rest.split_once('?').unwrap_or((rest, ""));
            let mut baud = DEFAULT_BAUD;
            for pair in query.split('&').filter(|p| !p.is_empty()) {
                match pair.split_once('=') {
                    Some(("baud", value)) => baud = value.parse().map_err(|_| bad())?,
                    _ => return Err(bad()),
                }
            }
            if path.is_empty() {
                return Err(bad());
            }
            return Ok(Endpoint::Serial {
                path: path.to_string(),
                baud,
            });
        }
        Err(bad())
    }
}

/// A connected byte stream to a sensor.
pub enum Link {
    Tcp(TcpStream),
    Serial(DuplexStream),
    /// In-process (tests under tokio's paused clock, an emulator in the same process).
    Memory(DuplexStream),
}

impl AsyncRead for Link {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        match self.get_mut() {
            Link::Tcp(s) => Pin::new(s).poll_read(cx, buf),
            Link::Serial(s) | Link::Memory(s) => Pin::new(s).poll_read(cx, buf),
        }
    }
}

impl AsyncWrite for Link {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        match self.get_mut() {
            Link::Tcp(s) => Pin::new(s).poll_write(cx, buf),
            Link::Serial(s) | Link::Memory(s) => Pin::new(s).poll_write(cx, buf),
        }
    }
    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        match self.get_mut() {
            Link::Tcp(s) => Pin::new(s).poll_flush(cx),
            Link::Serial(s) | Link::Memory(s) => Pin::new(s).poll_flush(cx),
        }
    }
    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        match self.get_mut() {
            Link::Tcp(s) => Pin::new(s).poll_shutdown(cx),
            Link::Serial(s) | Link::Memory(s) => Pin::new(s).poll_shutdown(cx),
        }
    }
}

/// Connects within `timeout`.
pub async fn connect(uri: &str, timeout: Duration) -> Result<Link, TransportError> {
    match Endpoint::parse(uri)? {
        Endpoint::Tcp { host, port } => {
            let connecting = TcpStream::connect((host.as_str(), port));
            let stream = tokio::time::timeout(timeout, connecting)
                .await
                .map_err(|_| TransportError::Timeout {
                    uri: uri.to_string(),
                    timeout,
                })?
                .map_err(|source| TransportError::Io {
                    uri: uri.to_string(),
                    source,
                })?;
            let _ = stream.set_nodelay(true);
            Ok(Link::Tcp(stream))
        }
        Endpoint::Serial { path, baud } => {
            let port = serialport::new(&path, baud)
                .timeout(Duration::from_millis(50))
                .open()
                .map_err(|source| TransportError::Serial {
                    path: path.clone(),
                    source,
                })?;
            let stream = bridge(port).map_err(|source| TransportError::Io {
                uri: uri.to_string(),
                source,
            })?;
            Ok(Link::Serial(stream))
        }
    }
}

/// Bridges a blocking serial port to an async stream: one thread reads the port, one writes
/// it. Both end when the returned stream is dropped (the reader within one port timeout).
pub fn bridge(port: Box<dyn serialport::SerialPort>) -> std::io::Result<DuplexStream> {
    let (ours, theirs) = tokio::io::duplex(64 * 1024);
    let (mut from_async, mut to_async) = tokio::io::split(theirs);
    let mut reader = port.try_clone().map_err(std::io::Error::other)?;
    let mut writer = port;
    let (read_tx, mut read_rx) = tokio::sync::mpsc::channel::<Vec<u8>>(64);
    let (write_tx, write_rx) = std::sync::mpsc::channel::<Vec<u8>>();
    std::thread::Builder::new()
        .name("serial-read".into())
        .spawn(move || {
            let mut buf = [0u8; 4096];
            loop {
                match reader.read(&mut buf) {
                    Ok(0) => return,
                    Ok(n) => {
                        if read_tx
                            .blocking_send(buf.get(..n).unwrap_or_default().to_vec())
                            .is_err()
                        {
                            return;
                        }
                    }
                    Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {
                        if read_tx.is_closed() {
                            return;
                        }
                    }
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                    Err(_) => return,
                }
            }
        })?;
    std::thread::Builder::new()
        .name("serial-write".into())
        .spawn(move || {
            while let Ok(bytes) = write_rx.recv() {
                if writer
                    .write_all(&bytes)
                    .and_then(|()| writer.flush())
                    .is_err()
                {
                    return;
                }
            }
        })?;
    // One task forwards both ways, so that whichever end goes away first ends it: when the
    // async side is dropped it drops the channels, and both threads let go of the port (the
    // reader within one port timeout) even if the port stays silent. Two separate tasks would
    // leave the reader waiting for bytes that never come, holding the port's exclusive lock
    // so that the next open of the same device fails.
    tokio::spawn(async move {
        let mut buf = vec![0u8; 4096];
        loop {
            tokio::select! {
                bytes = read_rx.recv() => match bytes {
                    Some(bytes) => {
                        if to_async.write_all(&bytes).await.is_err() {
                            return;
                        }
                    }
                    None => {
                        // The port is gone: end of stream for the async side.
                        let _ = to_async.shutdown().await;
                        return;
                    }
                },
                n = from_async.read(&mut buf) => match n {
                    Ok(0) | Err(_) => return,
                    Ok(n) => {
                        if write_tx.send(buf.get(..n).unwrap_or_default().to_vec()).is_err() {
                            return;
                        }
                    }
                },
            }
        }
    });
    Ok(ours)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uris_parse_and_bad_ones_say_what_is_expected() {
        assert_eq!(
            Endpoint::parse("tcp://192.168.0.10:10940").unwrap(),
            Endpoint::Tcp {
                host: "192.168.0.10".into(),
                port: 10940
            }
        );
        assert_eq!(
            Endpoint::parse("tcp://lidar").unwrap(),
            Endpoint::Tcp {
                host: "lidar".into(),
                port: 10940
            }
        );
        assert_eq!(
            Endpoint::parse("serial:///dev/ttyACM0?baud=19200").unwrap(),
            Endpoint::Serial {
                path: "/dev/ttyACM0".into(),
                baud: 19200
            }
        );
        let err = Endpoint::parse("udp://x").unwrap_err().to_string();
        assert!(err.contains("tcp://HOST:PORT"), "{err}");
        assert!(Endpoint::parse("tcp://:99").is_err());
        assert!(Endpoint::parse("serial:///dev/x?speed=1").is_err());
    }
}
