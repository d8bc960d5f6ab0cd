//! core's checks as one list: the firmware's `selftest` binary runs it on
//! the emulated Cortex-M4 (`cargo fw-test`), and the same list generates
//! one host `#[test]` per entry, so the two cannot drift apart.
//!
//! A check is a plain function returning `Err(reason)` on failure: no
//! unwinding, no test harness, nothing the target lacks. Each module keeps
//! its checks in its own `checks` module; this one only lists them.

/// What a check found: `Ok(())` or why it failed.
pub type Outcome = Result<(), &'static str>;

/// One check.
pub type Check = fn() -> Outcome;

/// `Err(failure)` unless `condition` holds: a check's assertion.
pub fn ensure(condition: bool, failure: &'static str) -> Outcome {
    if condition {
        Ok(())
    } else {
        Err(failure)
    }
}

/// The next xorshift32 state (`state` must not be 0): core's checks'
/// deterministic random numbers, the same on the host and the target.
pub fn xorshift32(state: &mut u32) -> u32 {
    *state ^= *state << 13;
    *state ^= *state >> 17;
    *state ^= *state << 5;
    *state
}

/// `checks! { module: [check, ...], ... }` lists `crate::module::checks::check`
/// as [`TESTS`] (named `module::check`) and as host `#[test]`s
/// (`selftest::host::module::check`).
macro_rules! checks {
    ($($module:ident: [$($check:ident),* $(,)?]),* $(,)?) => {
        /// Every check of core, `(name, function)`.
        pub const TESTS: &[(&str, Check)] = &[
            $($((concat!(stringify!($module), "::", stringify!($check)), crate::$module::checks::$check),)*)*
        ];

        #[cfg(test)]
        mod host {
            $(mod $module {
                $(#[test]
                fn $check() {
                    assert_eq!(crate::$module::checks::$check(), Ok(()));
                })*
            })*
        }
    };
}

checks! {
    kernels: [
        dsp_kernels_equal_portable,
        sad_of_long_rows_equals_plain,
        bilinear_line_equals_plain,
        bilinear_stretch_equals_plain,
        seed_statistics_equal_plain,
        pinhole_rows_equal_bilinear,
        copy_row_copies,
        mean_4x4_equals_plain,
        normal_terms_equal_plain,
        strongest_gradients_equal_plain,
        dot_shifts_equal_plain,
        residues_equal_plain,
        float_kernels_equal_reference,
        floor_round_equal_libm,
        hypotf_equals_libm,
        sincosf_equals_libm,
    ],
    gpa: [
        moved_sums_equal_sampled_lines,
    ],
    health: [
        alarm_is_asserted_until_a_frame_is_judged_clear,
        lost_frame_asserts_until_the_next_clear_frame,
        odometry_timeout_counts_only_while_waiting,
    ],
    protocol: [
        every_message_round_trips,
        rig_converts_both_ways,
        floats_round_trip_bit_for_bit,
        longest_rig_fits_a_line,
        known_lines_match_documentation,
        tables_keep_the_documented_order,
        non_finite_is_refused_by_encoder,
        malformed_lines_give_typed_errors,
        decoder_resynchronises_after_garbage,
        random_bytes_never_panic_and_valid_lines_survive,
    ],
}

#[cfg(test)]
mod tests {
    #[test]
    fn names_are_unique() {
        for (i, (name, _)) in super::TESTS.iter().enumerate() {
            assert!(super::TESTS[..i].iter().all(|(other, _)| other != name), "{name} listed twice");
        }
    }
}
