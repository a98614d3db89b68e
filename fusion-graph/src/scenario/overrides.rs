//! `--set a.b.c=value`: one assignment applied to a scenario's TOML before
//! it is read, so that an override is checked like the file itself.

use crate::ScenarioError;

/// Applies `a.b.c=value`; the value is read as TOML (`8`, `true`, `"x"`,
/// `[1, 2]`) or, failing that, as a bare string.
pub fn apply_override(table: &mut toml::Table, assignment: &str) -> Result<(), ScenarioError> {
    let bad = |message: &str| ScenarioError::Override {
        assignment: assignment.into(),
        message: message.into(),
    };
    let (key, raw) = assignment
        .split_once('=')
        .ok_or_else(|| bad("expected key=value"))?;
    let key = key.trim();
    if key.is_empty() {
        return Err(bad("the key is empty"));
    }
    let value = match toml::from_str::<toml::Table>(&format!("v = {}", raw.trim())) {
        Ok(mut t) => t.remove("v").expect("parsed a table with key v"),
        Err(_) => toml::Value::String(raw.trim().to_string()),
    };
    let parts: Vec<&str> = key.split('.').collect();
    let mut current = table;
    for part in &parts[..parts.len() - 1] {
        if is_optional_section(part) && !current.contains_key(*part) {
            current.insert(part.to_string(), toml::Value::Table(toml::Table::new()));
        }
        current = current
            .get_mut(*part)
            .ok_or_else(|| bad(&format!("no section `{part}` in the scenario")))?
            .as_table_mut()
            .ok_or_else(|| bad(&format!("`{part}` is not a section")))?;
    }
    let last = parts[parts.len() - 1];
    // A part's own parameters are its to check, not the schema's.
    let in_params = parts.len() >= 2 && is_params_table(parts[parts.len() - 2]);
    if !current.contains_key(last) && !is_optional_key(last) && !in_params {
        return Err(bad(&format!("no key `{last}` in the scenario")));
    }
    current.insert(last.to_string(), value);
    Ok(())
}

/// Sections that may be absent from a scenario file; `--set` creates them.
fn is_optional_section(section: &str) -> bool {
    matches!(section, "censoring" | "reference") || is_params_table(section)
}

/// The tables of parameters a protocol or a manager reads for itself.
fn is_params_table(section: &str) -> bool {
    matches!(section, "params" | "manager_params")
}

/// Keys that may be absent from a scenario file but can be set.
pub(super) fn is_optional_key(key: &str) -> bool {
    matches!(
        key,
        "faults"
            | "policy"
            | "budget"
            | "feedback"
            | "ignore_silence"
            | "listen_ms"
            | "process_noise"
            | "lo"
            | "hi"
            | "max_active_total"
            | "allow_disconnected"
            | "auxiliary_fim"
            | "accuracy"
            | "raw"
            | "min_speed"
            | "centralized"
            | "motion"
            | "link"
            | "grid"
            | "positions"
            | "per_cell"
            | "manager"
            | "params"
            | "manager_params"
            | "gate"
            | "start"
            | "near_field"
            | "kind"
            | "resampler"
    )
}
