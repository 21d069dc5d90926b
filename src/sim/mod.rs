//! Ray-cast simulator of floor plans, sensor models and people: fixtures with ground truth.

/// A floor plan that cannot be used, with the file and what is wrong.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct PlanError(pub String);
