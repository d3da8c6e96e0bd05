//! The names of lanealign's choices (presets, methods, frames, projections, ...): one spelling
//! for the command line, configuration files and output, defined once by each type's serde
//! derivation (`kebab-case` of the variant).

use serde::de::value::{Error as ValueError, StrDeserializer};
use serde::de::{DeserializeOwned, IntoDeserializer};

/// A name that is not one of the type's choices; says which ones are.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct NameError(String);

impl NameError {
    /// A name refused for what `message` says.
    pub(crate) fn new(message: String) -> Self {
        NameError(message)
    }
}

/// Parses a choice by its name, the way configuration files spell it: for example
/// `parse_name::<Preset>("kiss-icp")`. Unknown names give serde's message, which lists the
/// expected ones.
pub fn parse_name<T: DeserializeOwned>(name: &str) -> Result<T, NameError> {
    let de: StrDeserializer<'_, ValueError> = name.into_deserializer();
    T::deserialize(de).map_err(|e| NameError(e.to_string()))
}
