//! The GPA's own profile: where a frame's time went, per stage, by the
//! benchmark clock ([`Gpa::set_clock`](super::Gpa::set_clock)).

/// Where one frame's `on_kg_row` time went, in ticks of the clock given to
/// [`Gpa::set_clock`](super::Gpa::set_clock) (0 without one).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GpaProfile {
    /// The row's warp line, its usable columns and the warped keyframe band (2S+1 rows per KG row).
    pub warp: u32,
    /// Tolerant residue and the per-cell residue counts.
    pub residue: u32,
    /// Height hypotheses: warped samples, per-cell SADs, per-cell decision.
    pub parallax: u32,
    /// The (2S+1)^2-shift SAD with the seed's statistics, and the |diff| histogram.
    pub shift_search: u32,
    /// Copying the row into the new keyframe.
    pub keyframe_update: u32,
    /// The motion estimate (coarse search, pyramids, alignment), and the
    /// parts of it below.
    pub estimate: u32,
    /// Its coarse search (step 1).
    pub estimate_coarse: u32,
    /// Its image pyramids.
    pub estimate_pyramids: u32,
    /// Its alignments (step 2, every start tried).
    pub estimate_align: u32,
    /// Its check of the surface under the robot (step 3).
    pub estimate_nearest_surface: u32,
    /// Its search for a lower level (step 4).
    pub estimate_lower_level: u32,
    /// The seed's search around the prediction, when the estimate differs from it.
    pub seed_search: u32,
}

/// The benchmark clock and what it measured.
pub(super) struct Profiler {
    /// Instructions or ns; None: no profiling.
    pub(super) clock: Option<fn() -> u32>,
    pub(super) profile: GpaProfile,
}

impl Profiler {
    pub(super) const OFF: Profiler = Profiler {
        clock: None,
        profile: GpaProfile { warp: 0, residue: 0, parallax: 0, shift_search: 0, keyframe_update: 0, estimate: 0, estimate_coarse: 0, estimate_pyramids: 0, estimate_align: 0, estimate_nearest_surface: 0, estimate_lower_level: 0, seed_search: 0 },
    };

    #[inline(always)]
    pub(super) fn now(&self) -> u32 {
        match self.clock {
            Some(clock) => clock(),
            None => 0,
        }
    }

    /// Charges the ticks since `since` to `stage`; returns now.
    #[inline(always)]
    pub(super) fn charge(&mut self, since: u32, stage: fn(&mut GpaProfile) -> &mut u32) -> u32 {
        let now = self.now();
        let total = stage(&mut self.profile);
        *total = total.wrapping_add(now.wrapping_sub(since));
        now
    }
}
