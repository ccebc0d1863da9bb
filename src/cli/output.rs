//! Printing results: one JSON document with `--json`, human text otherwise.

use serde::Serialize;

/// Prints `value` as pretty JSON when `json` is set, else the text `human` makes.
pub fn emit<T: Serialize>(
    json: bool,
    value: &T,
    human: impl FnOnce(&T) -> String,
) -> anyhow::Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(value)?);
    } else {
        print!("{}", human(value));
    }
    Ok(())
}
