//! The Ascension Bird protocol (being written).
