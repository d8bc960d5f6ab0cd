//! rig.toml rewritten with a calibration's values: its sections' keys set,
//! its comments and layout kept (`flatland calibrate --write`).

use flatland_core::geometry::Mount;

/// rig.toml's text with the `[mount]` section's values replaced (comments
/// and the other sections kept; roll and yaw added when absent).
///
/// # Panics
/// When `original` is not TOML: it is a rig.toml the recording has read
/// (the command itself goes through [`with_section_values`], which reports).
pub fn calibrated_rig_toml(original: &str, mount: &Mount) -> String {
    with_section_values(original, "mount", &mount_values(mount)).expect("rig.toml is TOML: the recording read it")
}

/// The `[mount]` values of an estimate, for [`with_section_values`]: the
/// decimals rig.toml's readers need (0.1 mm, 0.001 degree).
pub fn mount_values(mount: &Mount) -> Vec<(&'static str, String)> {
    vec![
        ("height_mm", format!("{:.1}", mount.height_mm)),
        ("tilt_deg", format!("{:.3}", mount.tilt_deg)),
        ("roll_deg", format!("{:.3}", mount.roll_deg)),
        ("yaw_deg", format!("{:.3}", mount.yaw_deg)),
    ]
}

/// TOML text with `section`'s keys set to `values` (each a TOML value's
/// text, written as given): keys present are replaced in place, keeping
/// their comments, absent ones added after the section's last key, an
/// absent section added at the end. toml_edit keeps everything else as the
/// file spells it.
pub fn with_section_values(original: &str, section: &str, values: &[(&str, String)]) -> Result<String, toml_edit::TomlError> {
    let mut document: toml_edit::DocumentMut = original.parse()?;
    let table = document.entry(section).or_insert_with(toml_edit::table);
    let table = table.as_table_like_mut().expect("a [section] is a table: the recording read rig.toml's sections as tables");
    for (key, text) in values {
        let mut value: toml_edit::Value = text.parse()?;
        match table.get_mut(key).and_then(|item| item.as_value_mut()) {
            Some(old) => {
                // The old value's spacing and trailing comment.
                *value.decor_mut() = old.decor().clone();
                *old = value;
            }
            None => {
                value.decor_mut().clear();
                table.insert(key, toml_edit::Item::Value(value));
            }
        }
    }
    Ok(document.to_string())
}
