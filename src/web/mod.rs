//! The live page: what a person at the site opens in a browser to see the sensors, their
//! points and the map, and to place a sensor by hand. This module owns:
//!
//! - [`page`]: the page itself, one HTML file (script and style inline) compiled into the
//!   binary: nothing is fetched from the internet, there is no build step;
//! - [`server`]: its HTTP and WebSocket server (axum, on the daemon's tokio runtime) and the
//!   rules about who may connect (loopback, token, Host and Origin checks) and how much;
//! - [`bridge`]: what goes over the WebSocket. It subscribes to the status socket's
//!   [`Publisher`](crate::daemon::socket::Publisher) like a `watch` client, paces the scans
//!   per sensor, adds snapshots (status, poses, map), and answers requests with the status
//!   socket's own [`answer_request`](crate::daemon::socket::answer_request): one protocol,
//!   two transports.
//!
//! - [`foxglove`] (cargo feature `foxglove`, on by default): the same site as a Foxglove
//!   WebSocket server, for Foxglove and Lichtblick.

pub mod bridge;
#[cfg(feature = "foxglove")]
pub mod foxglove;
pub mod page;
pub mod server;

pub use bridge::PageSource;
pub use server::{WebError, WebServer};
