//! core's checks as one list, so the firmware's `selftest` binary can run
//! them on the emulated Cortex-M4 (the host runs each as a `#[test]`).
//!
//! A check is a plain function returning `Err(reason)` on failure: no
//! unwinding, no test harness, nothing the target lacks.

/// One check: `Ok(())` or why it failed.
pub type Check = fn() -> Result<(), &'static str>;

/// Every check of core, `(name, function)`.
pub const TESTS: &[(&str, Check)] = &[
    ("sad::dsp_kernels_equal_portable", crate::sad::checks::dsp_kernels_equal_portable),
    ("sad::bilinear_line_equals_plain", crate::sad::checks::bilinear_line_equals_plain),
    ("sad::seed_statistics_equal_plain", crate::sad::checks::seed_statistics_equal_plain),
    ("remap::pinhole_rows_equal_bilinear", crate::remap::checks::pinhole_rows_equal_bilinear),
    ("remap::copy_row_copies", crate::remap::checks::copy_row_copies),
    ("protocol::every_message_round_trips", crate::protocol::checks::every_message_round_trips),
    ("protocol::floats_round_trip_bit_for_bit", crate::protocol::checks::floats_round_trip_bit_for_bit),
    ("protocol::longest_rig_fits_a_line", crate::protocol::checks::longest_rig_fits_a_line),
    ("protocol::known_line_matches_documentation", crate::protocol::checks::known_line_matches_documentation),
    ("protocol::non_finite_is_refused_by_encoder", crate::protocol::checks::non_finite_is_refused_by_encoder),
    ("protocol::malformed_lines_give_typed_errors", crate::protocol::checks::malformed_lines_give_typed_errors),
    ("protocol::decoder_resynchronises_after_garbage", crate::protocol::checks::decoder_resynchronises_after_garbage),
    (
        "protocol::random_bytes_never_panic_and_valid_lines_survive",
        crate::protocol::checks::random_bytes_never_panic_and_valid_lines_survive,
    ),
];

#[cfg(test)]
mod tests {
    #[test]
    fn names_are_unique() {
        for (i, (name, _)) in super::TESTS.iter().enumerate() {
            assert!(super::TESTS[..i].iter().all(|(other, _)| other != name), "{name} listed twice");
        }
    }
}
