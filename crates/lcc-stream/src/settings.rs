//! The tool's settings file: the hub every command joins, set once.
//!
//! `config.toml` in the platform's configuration folder, `lcc-stream` beneath it
//! (`$XDG_CONFIG_HOME/lcc-stream/config.toml` or `~/.config/lcc-stream/config.toml` on Linux,
//! `~/Library/Application Support/lcc-stream/config.toml` on macOS,
//! `%APPDATA%\lcc-stream\config.toml` on Windows), or the file `LCC_STREAM_CONFIG` names:
//!
//! ```toml
//! hub = "192.168.1.20:12021"
//! ```
//!
//! `--connect` wins over `LCC_HUB`, which wins over the file. A file that is missing is no
//! error; one that cannot be read or parsed is, before any command runs.

use std::path::PathBuf;
use std::sync::OnceLock;

use serde::Deserialize;

/// What the settings file may say.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct Settings {
    /// The hub, HOST:PORT, of every command that has no `--connect` (nor `LCC_HUB`).
    hub: Option<String>,
}

static HUB: OnceLock<Option<String>> = OnceLock::new();

/// Where the settings file is looked for.
pub(crate) fn path() -> Option<PathBuf> {
    match std::env::var_os("LCC_STREAM_CONFIG") {
        Some(path) => Some(PathBuf::from(path)),
        None => dirs::config_dir().map(|dir| dir.join("lcc-stream").join("config.toml")),
    }
}

/// Reads the settings file once, at start; what is wrong with it, in words.
pub(crate) fn load() -> Result<(), String> {
    let settings = match path() {
        Some(path) => read(&path)?,
        None => Settings::default(),
    };
    let _ = HUB.set(settings.hub);
    Ok(())
}

fn read(path: &std::path::Path) -> Result<Settings, String> {
    let text = match std::fs::read_to_string(path) {
        Ok(text) => text,
        Err(error) if error.kind() == std::io::ErrorKind::NotFound => return Ok(Settings::default()),
        Err(error) => return Err(format!("cannot read the settings file {}: {error}", path.display())),
    };
    let settings: Settings =
        toml::from_str(&text).map_err(|e| format!("the settings file {}: {}", path.display(), e.message()))?;
    if let Some(hub) = &settings.hub {
        crate::args::hub_addr(hub).map_err(|e| format!("the settings file {}: hub: {e}", path.display()))?;
    }
    Ok(settings)
}

/// The hub the settings file names, if it does.
pub(crate) fn hub() -> Option<&'static str> {
    HUB.get().and_then(Option::as_deref)
}
