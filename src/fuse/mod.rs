//! The fused map: an occupancy grid of static structure and the files it is published as.
//! Pure: takes site-frame rays and points, returns grids and bytes.

pub mod export;
pub mod grid;

pub use export::{TaggedPoint, map_yaml, pgm, ply};
pub use grid::{Cell, GridParams, OccupancyGrid};
