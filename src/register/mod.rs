//! Registration: each sensor's pose from the scans alone. `pair` registers two scans (global
//! search, free-space check, refinement, verdict); `site` solves all sensors jointly; `motion`
//! checks poses against people both sensors saw walk; `walkers` proposes poses from them.

pub mod clocks;
pub mod hypotheses;
pub mod icp;
pub mod matching;
pub mod model;
pub mod motion;
pub mod pair;
pub mod params;
pub mod score;
pub mod site;
pub mod telling;
pub mod walkers;
pub mod zones;

pub use model::ScanModel;
pub use pair::{Abstain, Candidate, PairResult, polish, register_pair};
pub use params::RegisterParams;
