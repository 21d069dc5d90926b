//! The daemon: its config file, the status socket and its protocol, the state it keeps on
//! disk, its conversation with systemd (notifications, signals), the queue to the registration
//! worker and the scan-rate meter behind `status`; and the running pipeline wired from them:
//!
//! - [`pipeline`]: shared state (drivers' status, latest scans, poses) and the real
//!   [`socket::StatusSource`];
//! - [`pipeline_register`]: the registration worker thread and moved-sensor detection, on
//!   the scans' own clock (taken in stamp order by [`reorder`]);
//! - [`local_refine`]: a moved sensor aligned from its old pose before any global search;
//! - [`pipeline_fuse`]: fused frames, the occupancy grid and the map files;
//! - [`pipeline_track`]: the people tracker's thread, fed posed scans, publishing `TRACKS`;
//! - [`align_live`]: the placed site aligned to the building drawing (`building_from_site`);
//! - [`returns`]: how much each sensor sees (a covered lens is named, not guessed at);
//! - [`run`]: the lifecycle (emulators for `replay:`, driver tasks, socket, systemd, signals).

pub mod align_live;
pub mod config;
pub mod lines;
pub mod local_refine;
pub mod notify;
pub mod people_out;
pub mod pipeline;
pub mod pipeline_fuse;
pub mod pipeline_register;
pub mod pipeline_track;
pub mod priority;
pub mod protocol;
pub mod queue;
pub mod rate;
pub mod reorder;
pub mod returns;
pub mod run;
pub mod signals;
#[cfg(feature = "zenoh")]
pub mod site_map;
#[cfg(feature = "zenoh")]
pub mod site_net;
#[cfg(feature = "zenoh")]
pub mod site_tracks;
#[cfg(feature = "zenoh")]
pub mod site_view;
pub mod socket;
pub mod state;
pub mod surveys;
#[cfg(feature = "zenoh")]
pub mod zone_net;
