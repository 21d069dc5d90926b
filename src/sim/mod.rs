//! Ray-cast simulator of floor plans, sensor models and people: fixtures with ground truth.
//!
//! A [`Plan`] (TOML floor plan, see [`plan`]) becomes a [`Simulation`] that streams the scans
//! every sensor would make, with Hokuyo-like noise, dropouts, mixed pixels, intensities, people
//! walking and sensors being moved. Nothing here writes files: the `simulate` command does.
//!
//! - [`plan`]: the TOML format and its checks (every key documented there).
//! - `scene`: 3D ray casting against extruded 2D shapes, floor and ceiling.
//! - `sensor_model`: noise, dropouts, mixed pixels, intensity, spurious returns.
//! - `simulation`: timing, clocks, moves, people, streaming in stamp order, the people's truth.
//! - `crowd`, `walkable`: `[[crowd]]` and `[[queue]]` people, walking A* paths on an occupancy
//!   grid of the plan; `people`: how their bodies (legs, torso ellipse, head) are ray-cast.
//! - `overlap`: [`view_overlap`], how much two sensors see of the same walls.
//! - [`generate`]: seeded large floors (a concourse of N scanners) made as plans.
//!
//! Same plan and seed give bit-identical scans. Speed: `cargo bench --bench sim_speed` prints
//! how long a minute of `fixtures/plans/hall.toml` takes.

mod crowd;
pub mod generate;
mod overlap;
mod people;
pub mod plan;
mod scene;
mod sensor_model;
mod sightlines;
mod simulation;
mod walkable;

use std::fmt;

pub use overlap::view_overlap;
pub use sightlines::Sightlines;

/// A straight piece of wall: its two end points, m.
pub type WallPiece = ([f64; 2], [f64; 2]);

/// The plan's wall pieces with its doors cut out, as a drawing shows them.
pub fn wall_pieces(plan: &Plan) -> Result<Vec<WallPiece>, PlanError> {
    Ok(scene::Scene::build(plan)?.wall_pieces())
}
pub use plan::{BoxShape, Circle, Crowd, Door, Model, Move, Person, Plan, Queue, SensorPlan, Wall};
pub use simulation::{PEOPLE_TRUTH_PERIOD_NS, SimEvent, Simulation};

/// A floor plan that cannot be used: the file, the line when known, the key and what is valid.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlanError {
    /// The file (or other origin) the plan came from.
    pub file: String,
    /// 1-based line of the table or value at fault, when known.
    pub line: Option<usize>,
    /// The key at fault, e.g. `sensor.pitch_deg`.
    pub key: Option<String>,
    /// What is wrong and what would be valid.
    pub problem: String,
}

impl PlanError {
    pub(crate) fn new(file: &str, line: Option<usize>, key: Option<&str>, problem: String) -> Self {
        PlanError {
            file: file.to_string(),
            line,
            key: key.map(str::to_string),
            problem,
        }
    }
}

impl fmt::Display for PlanError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file)?;
        if let Some(line) = self.line {
            write!(f, ":{line}")?;
        }
        if let Some(key) = &self.key {
            write!(f, ": `{key}`")?;
        }
        write!(f, ": {}", self.problem)
    }
}

impl std::error::Error for PlanError {}
