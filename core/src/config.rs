//! The configuration vocabulary every crate shares: the integer policy and the checks that turn
//! raw settings into validated ones (range, required, not-for-this-case, unique, unknown keys).
//! Each check records a [`ConfigError`](crate::error::ConfigError) (`key = value: rule`) in one
//! [`ConfigErrors`] list, so a file's problems are all reported at once.
//!
//! # Integer policy
//! Every integer key is read as [`Int`] (`i64`, TOML's own integer type) and narrowed by
//! [`ConfigErrors::int`]. A negative or oversized value is then reported against its key with
//! the key's rule (`channels[0].channel = 300: must be 1..=18`) instead of failing the parse
//! with a message that names neither.
//!
//! # Tables built from shared pieces
//! serde's `deny_unknown_fields` does not combine with `flatten`: a struct with a flattened
//! field silently drops unknown keys. A table built from shared pieces (`#[serde(flatten)]`)
//! therefore ends with `#[serde(flatten)] unknown: UnknownKeys`, which collects every key no
//! piece took; [`UnknownKeys::check`] reports each against its key path, so the gateway points
//! at the misspelt key's own line. Tables that flatten nothing keep `deny_unknown_fields`.
//!
//! # Defaults
//! Each `validate(&mut self)` fills the default of every absent key that applies into the
//! settings it checks, so that afterwards they serialize as the effective config (what
//! `rove check-config --print` shows) and load again as the same validated config.

use crate::error::{ConfigErrors, Result};
use serde::de::{Deserializer, IgnoredAny, MapAccess, Visitor};
use serde::{Deserialize, Serialize, Serializer};
use std::collections::HashMap;
use std::fmt;
use std::hash::Hash;
use std::ops::RangeInclusive;

/// Config types written one documented field or variant a line: in a struct,
/// `name: Type => "doc",` stands for `#[doc = "doc"] pub name: Type,`; in an enum,
/// `Name => "doc",` for `#[doc = "doc"] Name,`, and a variant with data takes it after the doc:
/// `Name => "doc" (Type),` or `Name => "doc" { field: Type => "doc", },`. `pub settings Name`
/// is a struct with the derives of every table as written (`Debug, Clone, Default, PartialEq,
/// Serialize, Deserialize`) whose `Name::KNOWN` lists the keys it takes, for
/// [`UnknownKeys::check`]: its own and, for a `#[serde(flatten)]` field, the piece's `KEYS`.
/// `pub table Name` is one with the same derives that rejects unknown keys instead
/// (`deny_unknown_fields`: every table that flattens nothing, see the module docs) and lists
/// them in `Name::KEYS`.
/// `pub keyword Name` is an enum of the words a key takes, written in lower case in TOML
/// (`Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize`, `rename_all =
/// "lowercase"`; a variant of several words takes `#[serde(rename = "snake_case")]`).
/// `pub keyword Name -> Type` also maps each word to the value written after its doc,
/// `Word => "doc" = value,`, as `impl From<Name> for Type`.
/// Attributes (docs, derives, serde's) before an item, a field or a variant are kept.
#[macro_export]
macro_rules! config_types {
    () => {};
    ($(#[$attr:meta])* pub keyword $name:ident -> $target:ty {
        $($(#[$va:meta])* $variant:ident => $doc:literal = $value:expr,)*
    } $($rest:tt)*) => {
        impl From<$name> for $target {
            fn from(word: $name) -> $target {
                match word { $($name::$variant => $value,)* }
            }
        }
        $crate::config_types! {
            $(#[$attr])* pub keyword $name { $($(#[$va])* $variant => $doc,)* }
            $($rest)*
        }
    };
    ($(#[$attr:meta])* pub keyword $name:ident { $($body:tt)* } $($rest:tt)*) => {
        $crate::config_types! {
            #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
            #[derive(::serde::Serialize, ::serde::Deserialize)]
            #[serde(rename_all = "lowercase")]
            $(#[$attr])*
            pub enum $name { $($body)* }
            $($rest)*
        }
    };
    (@known [$($known:expr,)*]) => { &[$($known),*] };
    (@known [$($known:expr,)*] #[serde(flatten)] $field:ident: $ty:ty => $doc:literal,
        $($rest:tt)*) => {
        $crate::config_types!(@known [$($known,)* <$ty>::KEYS,] $($rest)*)
    };
    (@known [$($known:expr,)*] $(#[$a:meta])* $field:ident: $ty:ty => $doc:literal,
        $($rest:tt)*) => {
        $crate::config_types!(@known [$($known,)* &[stringify!($field)],] $($rest)*)
    };
    ($(#[$attr:meta])* pub table $name:ident $(<$($g:ident),+>)? {
        $($(#[$field_attr:meta])* $field:ident: $ty:ty => $doc:literal,)*
    } $($rest:tt)*) => {
        impl $(<$($g),+>)? $name $(<$($g),+>)? {
            /// The keys the table takes, as currently spelt.
            pub const KEYS: &'static [&'static str] = &[$(stringify!($field)),*];
        }
        $crate::config_types! {
            #[derive(Debug, Clone, Default, PartialEq, ::serde::Serialize, ::serde::Deserialize)]
            #[serde(deny_unknown_fields)]
            $(#[$attr])*
            pub struct $name $(<$($g),+>)? { $($(#[$field_attr])* $field: $ty => $doc,)* }
            $($rest)*
        }
    };
    ($(#[$attr:meta])* pub settings $name:ident $(<$($g:ident),+>)? {
        $($body:tt)*
    } $($rest:tt)*) => {
        impl $(<$($g),+>)? $name $(<$($g),+>)? {
            /// Every key the table takes, its own and its flattened pieces', in order.
            pub const KNOWN: &'static [&'static [&'static str]] =
                $crate::config_types!(@known [] $($body)*);
        }
        $crate::config_types! {
            #[derive(Debug, Clone, Default, PartialEq, ::serde::Serialize, ::serde::Deserialize)]
            $(#[$attr])*
            pub struct $name $(<$($g),+>)? { $($body)* }
            $($rest)*
        }
    };
    ($(#[$attr:meta])* pub struct $name:ident $(<$($g:ident),+>)? {
        $($(#[$field_attr:meta])* $field:ident: $ty:ty => $doc:literal,)*
    } $($rest:tt)*) => {
        $(#[$attr])*
        pub struct $name $(<$($g),+>)? {
            $($(#[$field_attr])* #[doc = $doc] pub $field: $ty,)*
        }
        $crate::config_types!($($rest)*);
    };
    ($(#[$attr:meta])* pub enum $name:ident {
        $($(#[$variant_attr:meta])* $variant:ident => $doc:literal $(($($ty:ty),+))?
            $({ $($(#[$fa:meta])* $field:ident: $field_ty:ty => $field_doc:literal,)* })?,)*
    } $($rest:tt)*) => {
        $(#[$attr])*
        pub enum $name {
            $($(#[$variant_attr])* #[doc = $doc] $variant $(($($ty),+))?
                $({ $($(#[$fa])* #[doc = $field_doc] $field: $field_ty,)* })?,)*
        }
        $crate::config_types!($($rest)*);
    };
}

/// How every integer key is read: wide, then range-checked by [`ConfigErrors::int`].
pub type Int = i64;

/// Older spellings still accepted (serde aliases), as (old, current): errors name the current
/// key and the gateway finds either on its line.
pub const ALIASES: &[(&str, &str)] = &[("invert", "reverse"), ("deadzone_pct", "deadband_pct")];

/// Shown as the value of a key that is absent but required.
pub const ABSENT: &str = "(absent)";

impl ConfigErrors {
    /// `value` narrowed to `T` if it lies in `range`; otherwise records
    /// `key = value: must be LO..=HI{unit}` (`unit` such as `" µs"` or `" (BCM GPIO number)"`).
    pub fn int<T: TryFrom<Int>>(
        &mut self,
        key: &str,
        value: Int,
        range: RangeInclusive<Int>,
        unit: &str,
    ) -> Option<T> {
        let narrowed = T::try_from(value).ok().filter(|_| range.contains(&value));
        if narrowed.is_none() {
            let rule = format!("must be {}..={}{unit}", range.start(), range.end());
            self.add(key, value, rule);
        }
        narrowed
    }

    /// [`ConfigErrors::int`] for an optional key: `None` stays `None` without an error.
    pub fn opt_int<T: TryFrom<Int>>(
        &mut self,
        key: &str,
        value: Option<Int>,
        range: RangeInclusive<Int>,
        unit: &str,
    ) -> Option<T> {
        value.and_then(|v| self.int(key, v, range, unit))
    }

    /// [`ConfigErrors::int`] for a required key: records `key = (absent): is required` if absent.
    pub fn req_int<T: TryFrom<Int>>(
        &mut self,
        key: &str,
        value: Option<Int>,
        range: RangeInclusive<Int>,
        unit: &str,
    ) -> Option<T> {
        self.required(key, &value)
            .and_then(|v| self.int(key, v, range, unit))
    }

    /// Runs `check` on a list of its own and files what it records under `prefix`.
    pub fn within<T>(&mut self, prefix: &str, check: impl FnOnce(&mut Self) -> T) -> T {
        let mut inner = ConfigErrors::default();
        let value = check(&mut inner);
        self.extend_within(prefix, inner);
        value
    }

    /// `value` if it is finite and lies in `range`; otherwise records `key = value: rule`.
    pub fn float(&mut self, key: &str, value: f64, range: RangeInclusive<f64>, rule: &str) -> f64 {
        if !(value.is_finite() && range.contains(&value)) {
            self.add(key, value, rule);
        }
        value
    }

    /// The value of a required key, or records `key = (absent): is required`.
    pub fn required<T: Clone>(&mut self, key: &str, value: &Option<T>) -> Option<T> {
        if value.is_none() {
            self.absent(key, "is required");
        }
        value.clone()
    }

    /// Records `key = (absent): rule` for a required key that was left out.
    pub fn absent(&mut self, key: &str, rule: impl Into<String>) {
        self.add(key, ABSENT, rule);
    }

    /// Records `key = value: rule` if the key was given although it does not apply (to this
    /// backend, source or method).
    pub fn not_for<V: fmt::Display>(&mut self, key: &str, value: Option<V>, rule: &str) {
        if let Some(v) = value {
            self.add(key, v, rule);
        }
    }

    /// The value of a nested section's validation, its problems filed under `prefix`; `None`
    /// if it had any (validation goes on, so that every problem is reported at once).
    pub fn section<T>(&mut self, prefix: &str, result: Result<T>) -> Option<T> {
        match result {
            Ok(value) => return Some(value),
            Err(crate::Error::Config(e)) => self.extend_within(prefix, e),
            Err(other) => self.add(prefix, "?", other.to_string()),
        }
        None
    }
}

/// The "must be unique" check: remembers who first used each value.
#[derive(Debug, Clone)]
pub struct Unique<K>(HashMap<K, String>);

impl<K> Default for Unique<K> {
    fn default() -> Self {
        Unique(HashMap::new())
    }
}

impl<K: Eq + Hash> Unique<K> {
    /// Records that `owner` (a key path such as `channels[2]`) uses `value`; if another owner
    /// used it first, returns that owner and records nothing.
    pub fn claim(&mut self, value: K, owner: impl Into<String>) -> Option<String> {
        let first = self.0.get(&value).cloned();
        if first.is_none() {
            self.0.insert(value, owner.into());
        }
        first
    }

    /// [`Unique::claim`], recording `key = shown: must be unique: FIRST {what}` on a repeat.
    pub fn check(
        &mut self,
        errors: &mut ConfigErrors,
        value: K,
        owner: impl Into<String>,
        (key, shown): (&str, impl fmt::Display),
        what: &str,
    ) {
        if let Some(first) = self.claim(value, owner) {
            let rule = format!("must be unique: {first} {what}");
            errors.add(key, shown, rule.trim_end());
        }
    }
}

/// The keys of a table that none of its flattened pieces took, with their values as written;
/// see the module docs. Always empty when serialized.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct UnknownKeys(pub Vec<(String, String)>);

impl UnknownKeys {
    /// None of its own: the keys it takes are the unknown ones.
    pub const KEYS: &'static [&'static str] = &[];

    /// Records `key = value: unknown key …` for each collected key; `known` lists the keys the
    /// table takes, for the message.
    pub fn check(&self, errors: &mut ConfigErrors, known: &[&[&str]]) {
        for (key, value) in &self.0 {
            let names: Vec<String> = (known.iter().flat_map(|k| k.iter()))
                .map(|k| format!("`{k}`"))
                .collect();
            let rule = format!("unknown key, expected one of {}", names.join(", "));
            errors.add(key.as_str(), value, rule);
        }
    }
}

impl Serialize for UnknownKeys {
    fn serialize<S: Serializer>(&self, serializer: S) -> std::result::Result<S::Ok, S::Error> {
        serializer.collect_map(std::iter::empty::<(&str, &str)>())
    }
}

impl<'de> Deserialize<'de> for UnknownKeys {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> std::result::Result<Self, D::Error> {
        struct Keys;
        impl<'de> Visitor<'de> for Keys {
            type Value = UnknownKeys;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("a table")
            }
            fn visit_map<A: MapAccess<'de>>(
                self,
                mut map: A,
            ) -> std::result::Result<UnknownKeys, A::Error> {
                let mut keys = Vec::new();
                while let Some(key) = map.next_key::<String>()? {
                    keys.push((key, map.next_value::<Shown>()?.text()));
                }
                Ok(UnknownKeys(keys))
            }
        }
        deserializer.deserialize_map(Keys)
    }
}

/// A value of any type, kept only as text for an error message.
#[derive(Deserialize)]
#[serde(untagged)]
enum Shown {
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(String),
    // The items are read only to be skipped.
    Seq(#[allow(dead_code)] Vec<IgnoredAny>),
    Map(#[allow(dead_code)] HashMap<String, IgnoredAny>),
}

impl Shown {
    fn text(self) -> String {
        match self {
            Shown::Bool(v) => v.to_string(),
            Shown::Int(v) => v.to_string(),
            Shown::Float(v) => v.to_string(),
            Shown::Str(v) => format!("{v:?}"),
            Shown::Seq(_) => "[…]".into(),
            Shown::Map(_) => "{…}".into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    crate::config_types! {
        /// A piece with an older spelling.
        pub table Piece {
            #[serde(alias = "b")] a: Option<Int> => "Spelt `b` before.",
        }
    }

    crate::config_types! {
        /// A table built from a piece.
        pub settings Table {
            name: Option<String> => "A key of its own.",
            #[serde(flatten)] piece: Piece => "The piece's keys.",
            #[serde(flatten)] unknown: UnknownKeys => "The others.",
        }
    }

    #[test]
    fn int_names_key_and_rule() {
        let mut errors = ConfigErrors::default();
        assert_eq!(errors.int::<u8>("pin", 12, 0..=27, ""), Some(12));
        assert_eq!(errors.int::<u8>("pin", 300, 0..=400, " (GPIO)"), None);
        assert_eq!(errors.opt_int::<u8>("pin", None, 0..=27, ""), None);
        assert_eq!(errors.to_string(), "pin = 300: must be 0..=400 (GPIO)");
    }

    #[test]
    fn flattened_pieces_take_aliases_and_leave_unknown_keys() {
        let t: Table =
            toml::from_str("name = \"x\"\nb = 3\nbogus = [1]\nc = \"s\"").expect("parses");
        assert_eq!(t.piece.a, Some(3));
        assert_eq!(t.name.as_deref(), Some("x"));
        let mut errors = ConfigErrors::default();
        t.unknown.check(&mut errors, Table::KNOWN);
        assert_eq!(
            errors.to_string(),
            "bogus = […]: unknown key, expected one of `name`, `a`\n\
             c = \"s\": unknown key, expected one of `name`, `a`"
        );
    }

    #[test]
    fn unique_reports_the_first_owner() {
        let mut errors = ConfigErrors::default();
        let mut names = Unique::default();
        names.check(
            &mut errors,
            "a",
            "channels[0]",
            ("name", "\"a\""),
            "has the same name",
        );
        names.check(
            &mut errors,
            "a",
            "channels[1]",
            ("name", "\"a\""),
            "has the same name",
        );
        assert_eq!(
            errors.to_string(),
            "name = \"a\": must be unique: channels[0] has the same name"
        );
    }
}
