//! scanfuse: drives several Hokuyo laser scanners, works out where each one stands from the
//! scans alone, keeps that up to date, and publishes one fused map.
//!
//! Every stage is usable alone; see `DESIGN.md` in the repository for the data flow.

pub mod daemon;
pub mod drawing;
pub mod emulator;
pub mod features;
pub mod fuse;
pub mod geometry;
pub mod human;
pub mod record;
pub mod register;
pub mod scan;
pub mod scip;
pub mod sensor;
pub mod sim;
pub mod track;
pub mod web;
