//! Every feature-extraction threshold in one place (METHOD §2), with defaults that hold for
//! the UTM-30LX-EW (270°, 0.25°), the UXM-30LX-E (190°, 0.25°) and 180° SICK-class scans (0.5–1°).

/// Thresholds for grouping, segments, merging, edge points and point classes.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureParams {
    /// T_pdist at zero range: neighbours farther apart start a new group (m).
    pub group_gap_m: f64,
    /// T_pdist grows by this many beam spacings at the point's range, so sparse far walls
    /// (and walls seen at a grazing angle) stay one group.
    pub group_gap_beams: f64,
    /// Groups with fewer points are clutter and dropped.
    pub min_group_points: usize,
    /// T_lp: a point extends a line while it lies this close to it (m).
    pub line_tolerance_m: f64,
    /// Normal-angle step of the Hough sweep through the seed point (rad).
    pub hough_step_rad: f64,
    /// A segment needs at least this many points.
    pub min_segment_points: usize,
    /// T_len: shorter segments are dropped after merging (m).
    pub min_segment_len_m: f64,
    /// T_angle: segments this close in direction may merge (rad).
    pub merge_angle_rad: f64,
    /// T_ed: …when some pair of their endpoints is this close (m)…
    pub merge_endpoint_gap_m: f64,
    /// …and each one's midpoint lies this close to the other's line (m).
    pub merge_line_dist_m: f64,
    /// The angle φ at a point is measured to the nearest neighbours at least this far away (m),
    /// so sensor noise on dense scans does not make every point a corner.
    pub edge_neighbour_m: f64,
    /// T_phi: a point with |φ| at most this is an edge point (rad); walls have |φ| ≈ π.
    pub edge_angle_rad: f64,
    /// Points this close to a corner take the corner's class (m).
    pub corner_radius_m: f64,
}

impl Default for FeatureParams {
    fn default() -> Self {
        FeatureParams {
            group_gap_m: 0.12,
            group_gap_beams: 4.0,
            min_group_points: 5,
            line_tolerance_m: 0.05,
            hough_step_rad: 1f64.to_radians(),
            min_segment_points: 8,
            min_segment_len_m: 0.5,
            merge_angle_rad: 3f64.to_radians(),
            merge_endpoint_gap_m: 0.5,
            merge_line_dist_m: 0.08,
            edge_neighbour_m: 0.15,
            edge_angle_rad: 130f64.to_radians(),
            corner_radius_m: 0.12,
        }
    }
}
