//! Reading a file and naming where an error is: `file:line: key = value: rule`.

use super::*;

pub(super) fn read(path: &Path) -> anyhow::Result<String> {
    std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))
}

pub(super) fn parse<T: for<'de> Deserialize<'de>>(path: &Path, text: &str) -> anyhow::Result<T> {
    toml::from_str(text).map_err(|e| {
        let line = e
            .span()
            .map(|span| text[..span.start.min(text.len())].matches('\n').count() + 1);
        let message = e.message().trim_end();
        match line {
            Some(line) => anyhow!("{}:{line}: {message}", path.display()),
            None => anyhow!("{}: {message}", path.display()),
        }
    })
}

/// Turns validation errors into one message per problem, each `file:line: key = value: rule`.
pub(super) fn located(path: &Path, text: &str, error: rove_core::Error) -> anyhow::Error {
    match error {
        rove_core::Error::Config(errors) => {
            let lines: Vec<String> = errors
                .0
                .iter()
                .map(|e| match key_line(text, &e.key) {
                    Some(line) => format!("{}:{line}: {e}", path.display()),
                    None => format!("{}: {e}", path.display()),
                })
                .collect();
            anyhow!("{}", lines.join("\n"))
        }
        other => anyhow!("{}: {other}", path.display()),
    }
}

/// The 1-based line where the dotted `key` (`operator.stream_hz`, `output.channels[2].max_us`,
/// `hierarchy.mobile.laptop` in an inline table, `operator.drive[1]`) is written, from the
/// parsed document's own positions; a key in an older spelling counts as its current name. An
/// absent key (left to a default that broke a rule) points at the nearest table that holds it;
/// `None` if nothing of it is in the file.
pub fn key_line(text: &str, key: &str) -> Option<usize> {
    use toml_edit::{Item, TableLike, Value};
    let doc = toml_edit::ImDocument::parse(text).ok()?;
    // The byte offset of the deepest part of `key` found so far.
    let (mut table, mut at): (&dyn TableLike, Option<usize>) = (doc.as_table(), None);
    for segment in key.split('.') {
        let (name, index) = match segment.split_once('[') {
            Some((name, i)) => (name, i.trim_end_matches(']').parse::<usize>().ok()),
            None => (segment, None),
        };
        let old = rove_core::config::ALIASES
            .iter()
            .filter(|(_, new)| *new == name);
        let names = std::iter::once(name).chain(old.map(|(old, _)| *old));
        let Some((k, item)) = names.into_iter().find_map(|n| table.get_key_value(n)) else {
            break;
        };
        at = k.span().or(item.span()).map(|span| span.start).or(at);
        let next = match (item, index) {
            (Item::ArrayOfTables(tables), Some(i)) => tables.get(i).map(|t| {
                at = t.span().map(|span| span.start).or(at);
                t as &dyn TableLike
            }),
            (Item::Value(Value::Array(values)), Some(i)) => values.get(i).and_then(|v| {
                at = v.span().map(|span| span.start).or(at);
                v.as_inline_table().map(|t| t as &dyn TableLike)
            }),
            (item, _) => item.as_table_like(),
        };
        let Some(next) = next else { break };
        table = next;
    }
    at.map(|at| text[..at.min(text.len())].matches('\n').count() + 1)
}
