//! `[output]`: the list of output adapters, one line each, and the adapter-neutral types the
//! rest of the gateway uses: the settings as written ([`OutputSection`]) and validated
//! ([`OutputConfig`]). An adapter crate says what it takes and what it needs through
//! [`rove_core::adapter::OutputKind`] and [`OutputSpec`]; nothing here knows one adapter from
//! another.

use super::*;
use rove_core::adapter::{Need, OutputKind, OutputSpec};
use std::fmt;

/// Every output adapter `[output] adapter` can name. Adding an adapter is its crate, its
/// dependency line in gateway/Cargo.toml, and one line here (docs/design.md, "Adding an output
/// adapter").
pub const ADAPTERS: &[Adapter] = &[
    Adapter::of::<rove_core::sim::Sim>(),
    Adapter::of::<rove_pwm::Pwm>(),
    Adapter::of::<rove_eyedrive::Eyedrive>(),
    Adapter::of::<rove_naza::Naza>(),
    Adapter::of::<rove_mavlink::Mavlink>(),
    Adapter::of::<rove_can::Can>(),
    Adapter::of::<rove_ros2::Ros2>(),
];

/// One output adapter as the gateway knows it.
#[derive(Clone, Copy)]
pub struct Adapter {
    /// `[output] adapter = "NAME"`.
    pub name: &'static str,
    /// What it drives, in one line.
    pub summary: &'static str,
    /// Reads a vehicle file whose `[output]` holds this adapter's settings.
    read: fn(&Path, &str) -> anyhow::Result<RawVehicle<OutputSection>>,
}

impl fmt::Debug for Adapter {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Adapter").field("name", &self.name).finish()
    }
}

impl Adapter {
    const fn of<K: OutputKind + 'static>() -> Adapter {
        Adapter {
            name: K::NAME,
            summary: K::SUMMARY,
            read: read_as::<K>,
        }
    }
}

fn read_as<K: OutputKind + 'static>(
    path: &Path,
    text: &str,
) -> anyhow::Result<RawVehicle<OutputSection>> {
    let file: RawVehicle<K::Settings> = parse(path, text)?;
    Ok(file.with_output(|settings| OutputSection {
        adapter: K::NAME,
        settings: Box::new(Written::<K>(settings)),
    }))
}

/// `[output]` as written: the adapter's name and its own settings.
pub struct OutputSection {
    adapter: &'static str,
    settings: Box<dyn Settings>,
}

/// One adapter's settings, whatever their type.
trait Settings: fmt::Debug + Send + Sync {
    fn validate(&mut self) -> rove_core::Result<Box<dyn OutputSpec>>;
    fn to_table(&self) -> Result<toml::Table, toml::ser::Error>;
}

struct Written<K: OutputKind>(K::Settings);

impl<K: OutputKind> fmt::Debug for Written<K> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
}

impl<K: OutputKind> Settings for Written<K> {
    fn validate(&mut self) -> rove_core::Result<Box<dyn OutputSpec>> {
        K::validate(&mut self.0)
    }

    fn to_table(&self) -> Result<toml::Table, toml::ser::Error> {
        toml::Table::try_from(&self.0)
    }
}

impl fmt::Debug for OutputSection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("OutputSection")
            .field("adapter", &self.adapter)
            .field("settings", &self.settings)
            .finish()
    }
}

/// The effective `[output]`: `adapter` and the settings with their defaults filled in.
impl Serialize for OutputSection {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut table = self
            .settings
            .to_table()
            .map_err(serde::ser::Error::custom)?;
        table.insert("adapter".into(), self.adapter.into());
        table.serialize(serializer)
    }
}

impl OutputSection {
    pub(super) fn validate(&mut self, errors: &mut ConfigErrors) -> OutputConfig {
        let spec = errors.section("output", self.settings.validate());
        OutputConfig {
            adapter: self.adapter,
            spec: spec.unwrap_or_else(|| Box::new(rove_core::sim::Sim)),
        }
    }
}

/// A validated `[output]`: the adapter's name and what it opens.
#[derive(Debug, Clone)]
pub struct OutputConfig {
    adapter: &'static str,
    spec: Box<dyn OutputSpec>,
}

impl OutputConfig {
    /// The recording sim output.
    pub fn sim() -> OutputConfig {
        OutputConfig {
            adapter: <rove_core::sim::Sim as OutputKind>::NAME,
            spec: Box::new(rove_core::sim::Sim),
        }
    }

    /// The adapter's name as `[output] adapter` spells it.
    pub fn adapter(&self) -> &'static str {
        self.adapter
    }

    /// What the adapter opens and needs.
    pub fn spec(&self) -> &dyn OutputSpec {
        &*self.spec
    }

    /// What the adapter needs of the computer.
    pub fn needs(&self) -> Vec<Need> {
        self.spec.needs()
    }

    /// Gives an adapter that keeps what it learns of its device ([`Need::Memory`]) its file.
    pub fn remember_in(&mut self, file: std::path::PathBuf) {
        self.spec.remember_in(file);
    }
}

/// Reads a vehicle file in two steps so that errors inside `[output]` keep their lines: first
/// `adapter`, then the same text, with the `adapter` key blanked (every byte offset and line
/// unchanged), as that adapter's settings.
pub(super) fn parse_vehicle(path: &Path, text: &str) -> anyhow::Result<RawVehicle<OutputSection>> {
    #[derive(Deserialize)]
    struct Probe {
        output: Option<ProbeOutput>,
    }
    #[derive(Deserialize)]
    struct ProbeOutput {
        adapter: Option<toml::Spanned<String>>,
    }
    let probe: Probe = parse(path, text)?;
    let adapter = probe.output.and_then(|o| o.adapter);
    let entry = (adapter.as_ref()).and_then(|a| ADAPTERS.iter().find(|e| e.name == a.get_ref()));
    let (Some(adapter), Some(entry)) = (adapter.as_ref(), entry) else {
        let list: Vec<String> = (ADAPTERS.iter())
            .map(|a| format!("\n  {:?}: {}", a.name, a.summary))
            .collect();
        let written = adapter.map_or(ABSENT.to_string(), |a| format!("{:?}", a.get_ref()));
        let rule = format!("names the output adapter, one of:{}", list.concat());
        let error = rove_core::error::ConfigError::new("output.adapter", written, rule);
        return Err(located(
            path,
            text,
            rove_core::Error::Config(ConfigErrors(vec![error])),
        ));
    };
    (entry.read)(path, &blank_key_value(text, adapter.span()))
}

/// `text` with the key/value pair whose value spans `value` replaced by spaces (newlines
/// kept), together with the comma that separates it in an inline table.
pub(super) fn blank_key_value(text: &str, value: std::ops::Range<usize>) -> String {
    let bytes = text.as_bytes();
    let is_key = |b: u8| b.is_ascii_alphanumeric() || b"_-.\"' \t=".contains(&b);
    let mut start = value.start.min(bytes.len());
    while start > 0 && is_key(bytes[start - 1]) {
        start -= 1;
    }
    let mut end = value.end.min(bytes.len());
    let after = text[end..].trim_start_matches([' ', '\t']);
    if after.starts_with(',') {
        end = text.len() - after.len() + 1;
    } else if text[..start].trim_end_matches([' ', '\t']).ends_with(',') {
        start = text[..start].trim_end_matches([' ', '\t']).len() - 1;
    }
    // One space per byte (newlines kept), so no offset or line after the blank moves.
    let blank: String = (text[start..end].chars())
        .flat_map(|c| std::iter::repeat_n(if c == '\n' { c } else { ' ' }, c.len_utf8()))
        .collect();
    format!("{}{blank}{}", &text[..start], &text[end..])
}
