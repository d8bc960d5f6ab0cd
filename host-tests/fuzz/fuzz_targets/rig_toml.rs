//! rig.toml reader: any text gives a valid rig or a located error, and a
//! rig it accepts must build a grid and table without panicking.
#![no_main]

use flatland_core::grid::{GridConfig, KgGrid};
use flatland_core::remap::RemapTable;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let Ok((rig, _)) = flatland_host::recording::parse_rig(Path::new("rig.toml"), text) else { return };
    if let Ok(grid) = KgGrid::for_rig(&rig, &GridConfig::default()) {
        let _ = RemapTable::new(&rig, &grid);
    }
});
