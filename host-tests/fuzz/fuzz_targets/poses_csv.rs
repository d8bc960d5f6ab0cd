//! poses.csv reader: accepted rows are finite and strictly increasing in frame.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    match flatland_host::recording::parse_poses(Path::new("poses.csv"), text) {
        Ok(rows) => {
            assert!(!rows.is_empty());
            for row in &rows {
                assert!(row.t_s.is_finite());
                if let Some(pose) = row.pose {
                    assert!(pose.x_mm.is_finite() && pose.z_mm.is_finite() && pose.yaw_deg.is_finite());
                }
                if let Some(attitude) = row.attitude {
                    assert!(attitude.pitch_deg.is_finite() && attitude.roll_deg.is_finite());
                }
            }
            assert!(rows.windows(2).all(|w| w[0].frame < w[1].frame));
        }
        Err(error) => {
            // Every error names the file and a line.
            let message = error.to_string();
            assert!(message.starts_with("poses.csv:"), "{message}");
        }
    }
});
